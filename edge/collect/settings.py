"""What the collector needs to know about one machine, as plain frozen values.

edge.service.settings builds these from the config (`machine_settings`); the poller, the plan, the path check
and the axis-number probe read only these, so collect never depends on how the YAML is validated. The values
are the config's, already resolved (metric names, PMC targets, the time zone): every decision about what to
read and when stays in edge.collect.plan, which builds the plan from these per session, once the static reads
have said which axes and spindles the control has.
"""

from __future__ import annotations

from dataclasses import dataclass
from zoneinfo import ZoneInfo

from edge.focas.targets import PmcTarget


@dataclass(frozen=True, slots=True)
class Periods:
    """How often each poll group is read, in seconds (static data: once per connection)."""

    status: float
    macros: float
    pmc: float
    params: float
    diags: float
    loads: float
    counters: float
    alarm_history: float


@dataclass(frozen=True, slots=True)
class MacroValues:
    """Macro variables first..last, one metric name per number."""

    first: int
    last: int
    names: tuple[str, ...]
    deadband: float


@dataclass(frozen=True, slots=True)
class PmcValues:
    """A PMC range (byte addresses, element type) and one metric name per element, or per bit with `bits`."""

    target: PmcTarget
    bits: bool
    names: tuple[str, ...]
    deadband: float


@dataclass(frozen=True, slots=True)
class NumberedValue:
    """One parameter or diagnosis number: axis 0 is the whole CNC, ALL_AXES every axis in one read."""

    number: int
    axis: int
    name: str  # the metric name; a per-axis read publishes `<name>/<axis name>`
    deadband: float


@dataclass(frozen=True, slots=True)
class PollSettings:
    """What the config asks to poll on one machine (the config's `poll` and the machine's alarm mode)."""

    periods: Periods
    positions: tuple[str, ...]
    part_count: bool
    program_name: bool
    operator_messages: bool
    servo_load: bool
    timers: bool
    tool_offsets: int
    work_offsets: tuple[int, ...]
    modal: bool
    tool_number: bool
    macros: tuple[MacroValues, ...]
    pmc: tuple[PmcValues, ...]
    params: tuple[NumberedValue, ...]
    diags: tuple[NumberedValue, ...]
    alarm_history: bool  # alarm mode ActivePlusHistory: the history ring is read too
    alarm_history_depth: int
    retry_dropped: float  # a function dropped after EW_FUNC/EW_NOOPT is tried again this long after


@dataclass(frozen=True, slots=True)
class Timeouts:
    connect_s: float
    request_s: float
    backoff_initial_s: float
    backoff_max_s: float


@dataclass(frozen=True, slots=True)
class MachineSettings:
    """One polled device: a machine, or one further path of a multi-path control (`<id>-path<n>`)."""

    id: str
    transport: str  # "focas" (native) or "packed"
    endpoint: str  # what open_session takes: host:port, tcp:host:port or unix:/path
    fwlib_host: str | None  # a FOCAS library host beside the native connection
    max_subpackets: int | None
    timeouts: Timeouts
    zone: ZoneInfo
    max_skew_s: float
    path: int  # the CNC path this device's session reads
    path_devices: tuple[str, ...]  # the ids of every path device of this control, path 1 first
    poll: PollSettings
    series: str | None = None  # as configured; shown until the control answers its own

    @property
    def paths(self) -> int:
        """The paths configured for this device's control."""
        return len(self.path_devices)
