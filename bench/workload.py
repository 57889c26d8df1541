"""The realistic per-tick plan every benchmark shares: status group, 10 macros, 4 PMC ranges, clock.

The same plan appears twice: as read items (codec and round-trip benchmarks) and as a daemon config
section (fleet benchmark), so both measure the same work.
"""

from __future__ import annotations

from edge.focas import items as it
from edge.focas.model import PmcType

MACRO_FIRST, MACRO_LAST = 500, 509
STAMP_MACRO = 509  # the fleet simulator sets this one to its own wall-clock time (seconds mod 1000)
CLOCK_MACRO = 508  # and answers this one with its CNC clock at the moment it answers (timestamp error)
PMC_RANGES = (("R", 100, 103, PmcType.BYTE), ("D", 2204, 2207, PmcType.WORD), ("G", 0, 7, PmcType.BYTE),
              ("F", 0, 3, PmcType.BYTE))


def tick_items() -> list[it.ReadItem]:
    """One poll tick's reads, as the collector batches them for the plan below (16 native subpackets)."""
    status: list[it.ReadItem] = [
        it.ReadStatus(), it.ReadAlarmStatus(), it.ReadProgramNumber(), it.ReadSequenceNumber(), it.ReadFeed(),
        it.ReadSpindleSpeed(), it.ReadSpindleLoad(), it.ReadPositions("absolute"), it.ReadParams(6711, 6711),
    ]
    pmc = [it.ReadPmc(area, start, end, dtype) for area, start, end, dtype in PMC_RANGES]
    return [*status, it.ReadMacros(MACRO_FIRST, MACRO_LAST), *pmc, it.ReadClock()]


def daemon_tick_items(period_s: float = 0.1) -> tuple[it.ReadItem, ...]:
    """The request the daemon sends on a tick of the status, macro and PMC groups for the config below: the
    plan's reads of those groups (program name, main path and operator messages beside tick_items'), then
    the clock. The floor measures this, so its round trip is the daemon's, however the plan grows."""
    from edge.collect import plan as pl  # the bench's other users need only the items
    from edge.config import parse_config
    from edge.service.settings import machine_settings

    config = parse_config("mqtt: {host: 127.0.0.1, sparkplug: {group_id: bench, edge_node_id: gw}}\n"
                          f"machines:\n{machines_section([8193], period_s)}", "workload", {})
    plan = pl.MachinePlan.build(machine_settings(config, config.machines[0]).poll)
    reads = plan.reads_for({pl.Group.STATUS, pl.Group.MACROS, pl.Group.PMC})
    return (*(read.item for read in reads), it.ReadClock())


def machines_section(ports: list[int], period_s: float, same_plan: bool = False) -> str:
    """The `machines:` entries of a daemon config for simulated CNCs on these local ports, this plan each."""
    poll = poll_section(period_s, same_plan)
    return "".join(f"  - {{id: m{i + 1:03d}, host: 127.0.0.1, port: {port}, poll: {poll}}}\n"
                   for i, port in enumerate(ports))


def poll_section(period_s: float, same_plan: bool = False) -> str:
    """The `poll:` YAML of one machine for the same plan: status, macros and PMC every `period_s`; servo loads
    (1 s) and counters (10 s) at their defaults, or every `period_s` when it is slower (a machine polled every
    3 s must not tick every second for its loads).

    `same_plan`: loads every 10th and counters every 100th tick at any period, as the defaults are at 10 Hz,
    so two fleets at different periods do the same reads per cycle (issue 25 compares their CPU per cycle)."""
    loads, counters = (10 * period_s, 100 * period_s) if same_plan else (max(period_s, 1.0), max(period_s, 10.0))
    pmc = ", ".join(f"{{range: {a}{s}-{a}{e}, data_type: {t.name.lower()}}}" for a, s, e, t in PMC_RANGES)
    return (f"{{periods: {{status: {period_s}, macros: {period_s}, pmc: {period_s}, loads: {loads:g}, "
            f"counters: {counters:g}}}, macros: [{MACRO_FIRST}-{MACRO_LAST}], pmc: [{pmc}]}}")
