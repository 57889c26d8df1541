"""The named reads of `focas-edge read` (sysinfo, status, program, loads, timers ...): which read items
each needs, which of them may fail alone, and how their results become the printed value.

Every function the client has is reachable here by one name. A composite read (one that gathers several
functions) degrades part by part, as the daemon degrades per function: each part names the items it needs;
a part with a refused item (a position kind an EDM does not have, the executing program's name on a 16i-W,
spindle names on a 31i lathe) is left out of the value and named with its return code; the read fails only
when every part was refused.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from edge.focas import items as it

Shaper = Callable[[list[Any]], object]

TIMER_KINDS = ("power_on", "operating", "cutting", "cycle", "free")  # cnc_rdtimer type 0..4
TOOL_OFFSETS_SHOWN = 16  # offsets 1..16 of each kind


Parts = dict[str, tuple[int, ...]]  # part name -> indices of the items it needs


@dataclass(frozen=True, slots=True)
class NamedRead:
    """The read items of one named read; `parts` names what may fail alone: each part lists the indices of the
    items it needs (axis names serve every position kind). The shaper gets None for every refused item, so it
    leaves out what those items fed."""

    items: tuple[it.ReadItem, ...]
    shape: Shaper
    parts: Parts = field(default_factory=dict)


def _by_name(names: Sequence[object] | None, values: Sequence[object] | None) -> dict[str, object] | None:
    if names is None or values is None:
        return None
    return {str(name): value for name, value in zip(names, values, strict=False)}


def _positions(results: list[Any]) -> object:
    names, *kinds = results
    table: dict[str, dict[str, object]] = {}
    for kind, values in zip(it.POSITION_KINDS, kinds, strict=True):
        if values is None or names is None:  # this kind was refused
            continue
        for name, value in zip(names, values, strict=False):
            table.setdefault(str(name), {})[kind] = value
    return table


def _program(results: list[Any]) -> object:
    numbers, sequence, executing, path = results
    value: dict[str, object] = {}
    if numbers is not None:
        value |= {"running": numbers.running, "main": numbers.main}
    if sequence is not None:
        value["sequence"] = sequence
    if executing is not None:
        value["name"] = executing.name
    if path is not None:
        value["path"] = path
    return value


def _loads(results: list[Any]) -> object:
    axes, servo, spindles, spindle = results
    loads = {"servo": _by_name(axes, servo), "spindle": _by_name(spindles, spindle)}
    return {kind: value for kind, value in loads.items() if value is not None}


def _tool_offsets(results: list[Any]) -> object:
    """{offset number: {kind: value}} for the kinds the control answered."""
    table: dict[str, dict[str, object]] = {}
    for kind, values in zip(it.TOOL_OFFSET_KINDS, results, strict=True):
        for number, value in enumerate(values or (), start=1):
            table.setdefault(str(number), {})[kind] = value
    return table


WORK_OFFSET_CODES = tuple(f"G{it.WORK_OFFSET_FIRST_G + n}" for n in range(6))  # cnc_rdzofs 1..6


def _work_offsets(results: list[Any]) -> object:
    """{G54: {axis name: value}, ...} for the offsets the control (its library host) answered."""
    names, *offsets = results
    return {code: _by_name(names, values) for code, values in zip(WORK_OFFSET_CODES, offsets, strict=True)
            if values is not None}


def _named_parts(names: Sequence[str], first: int = 0, shared: tuple[int, ...] = ()) -> Parts:
    """One part per name, on consecutive items from `first`, each also needing the `shared` items."""
    return {name: (*shared, first + index) for index, name in enumerate(names)}


def _dropping_none(names: Sequence[str]) -> Shaper:
    return lambda results: {n: v for n, v in zip(names, results, strict=True) if v is not None}


NAMED_READS: dict[str, NamedRead] = {
    "sysinfo": NamedRead((it.ReadSysInfo(),), lambda r: r[0]),
    "status": NamedRead((it.ReadStatus(),), lambda r: r[0]),
    "alarms": NamedRead((it.ReadAlarmStatus(), it.ReadActiveAlarms(32)), _dropping_none(("status", "active")),
                        _named_parts(("status", "active"))),
    "program": NamedRead((it.ReadProgramNumber(), it.ReadSequenceNumber(), it.ReadExecProgramName(),
                          it.ReadMainProgramPath()), _program, _named_parts(("number", "sequence", "name", "path"))),
    "programs": NamedRead((it.ReadProgramDirectory(),), lambda r: r[0]),
    "positions": NamedRead((it.ReadAxisNames(), *(it.ReadPositions(kind) for kind in it.POSITION_KINDS)),
                           _positions, _named_parts(it.POSITION_KINDS, first=1, shared=(0,))),
    "axes": NamedRead((it.ReadAxisNames(), it.ReadControlledAxes()), _dropping_none(("names", "controlled")),
                      _named_parts(("names", "controlled"))),
    "spindles": NamedRead((it.ReadSpindleNames(),), lambda r: {"names": r[0]}),
    "speeds": NamedRead((it.ReadFeed(), it.ReadSpindleSpeed()), _dropping_none(("feed", "spindle")),
                        _named_parts(("feed", "spindle"))),
    "loads": NamedRead((it.ReadAxisNames(), it.ReadServoMeter(), it.ReadSpindleNames(), it.ReadSpindleLoad()),
                       _loads, {"servo": (0, 1), "spindle": (2, 3)}),
    "timers": NamedRead(tuple(it.ReadTimer(kind) for kind in range(len(TIMER_KINDS))),
                        _dropping_none(TIMER_KINDS), _named_parts(TIMER_KINDS)),
    "messages": NamedRead((it.ReadOperatorMessages(),), lambda r: r[0]),
    "tool_offsets": NamedRead(tuple(it.ReadToolOffsets(kind, 1, TOOL_OFFSETS_SHOWN)
                                    for kind in range(len(it.TOOL_OFFSET_KINDS))),
                              _tool_offsets, _named_parts(it.TOOL_OFFSET_KINDS)),
    "work_offsets": NamedRead((it.ReadAxisNames(), *(it.ReadWorkOffsets(n) for n in range(1, 7))),
                              _work_offsets, _named_parts(WORK_OFFSET_CODES, first=1, shared=(0,))),
    "modal": NamedRead((it.ReadModalGCodes(),), lambda r: {str(m.group): m.code for m in r[0]}),
    "tool_number": NamedRead((it.ReadToolNumber(),), lambda r: r[0]),
    "clock": NamedRead((it.ReadClock(),), lambda r: r[0]),
}
