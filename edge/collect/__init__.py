"""Collecting: one poller per machine, from the CNC's answers to change-filtered samples stamped with CNC time.

What lives here: the poll loop (poller: connect with backoff, static reads, one batched request per tick,
dropped functions), the plan it polls (plan: reads, groups, metrics, schedule; tick_batch: a tick's prepared
request), change detection (changes), the CNC clock (clock) and when a CNC answered (answer_time), active
alarms and the history watermark (alarms), the path count check (path_check), axis-type numbers
(axis_numbers), the shared wake-up grid (tickgrid), the start-up gate (start_gate), the counters (stats), what
it is told about a machine (settings), and the state in the MES vocabulary: the status word's table
(execution), the utilisation counters (utilisation) and the poller's hook for both (plant_state).

Rules:
1. collect may import edge.focas (client and codecs), edge.samples, edge.statefile and its own modules.
2. It never imports edge.config: it takes MachineSettings, which edge.service.settings builds from the config.
3. It never imports edge.publish, edge.command, edge.service or edge.cli: samples leave through a DeviceSink.
Other packages import collect through the names below.
"""

from edge.collect.axis_numbers import refused_as_axis_type
from edge.collect.plan import MachinePlan, PlannedRead, metric_values
from edge.collect.poller import DeviceSink, MachinePoller, SessionFactory, default_session
from edge.collect.settings import (
    MachineSettings,
    MacroValues,
    NumberedValue,
    Periods,
    PmcValues,
    PollSettings,
    Timeouts,
)
from edge.collect.start_gate import StartGate
from edge.collect.stats import CYCLE_BUCKETS
from edge.collect.tickgrid import TickGrid

__all__ = [
    "CYCLE_BUCKETS",
    "DeviceSink",
    "MachinePlan",
    "MachinePoller",
    "MachineSettings",
    "MacroValues",
    "NumberedValue",
    "Periods",
    "PlannedRead",
    "PmcValues",
    "PollSettings",
    "SessionFactory",
    "StartGate",
    "TickGrid",
    "Timeouts",
    "default_session",
    "metric_values",
    "refused_as_axis_type",
]
