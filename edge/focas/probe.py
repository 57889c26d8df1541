"""Probe one CNC: identify it, try every read function once, and say which work and how fast.

An integration engineer writes a poll plan from this: a function that answers EW_FUNC or EW_NOOPT does
not exist on this control (or lacks its option), one that answers another EW code exists but did not
like the arguments, and the round-trip time of each says what a tick will cost. Writes are never sent:
the probe reports, per write operation, whether the transport has it and whether the read it pairs
with works, which is all that can be known without changing the machine.

On the native transport the parameter and diagnosis reads are also tried in the record form the
control was NOT identified as using (0x0e/0x30 on a 30i, 0x8d/0x93 on a 16i): a control that answers
both, or neither, is worth knowing about before writing a plan.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from edge.focas import items as it
from edge.focas.errors import EW_FUNC, EW_NOOPT, CncError, FocasError, NotSupported
from edge.focas.model import ParamRecord, PmcType, SysInfo
from edge.focas.paths import path_count
from edge.focas.routed import LIBRARY, NATIVE
from edge.focas.session import CncSession

ROUTES = (NATIVE, LIBRARY, "-")  # the per-function transports a routed machine reports


class Outcome:
    """What one probed function did (string constants, so the JSON output is self-explaining)."""

    OK = "ok"  # answered with data
    NOT_AVAILABLE = "not-available"  # EW_FUNC / EW_NOOPT: the control lacks the function or its option
    CNC_ERROR = "cnc-error"  # another EW code: the function exists, these arguments did not suit it
    NOT_SUPPORTED = "not-supported"  # the transport has no wire form for it; nothing was sent
    FAILED = "failed"  # timeout, protocol or connection trouble


@dataclass(frozen=True, slots=True)
class ProbeStep:
    """One function tried once: what was asked, what came back, how long the round trip took."""

    function: str  # the read item's name, e.g. ReadParams
    arguments: str  # e.g. "6711..6711 axis 0"
    outcome: str
    rtt_ms: float | None  # None when nothing went on the wire
    command: str = ""  # native command code(s), e.g. "0x8d"
    ew_code: int | None = None
    ew_name: str = ""
    detail: str = ""  # a short value summary, or the error message
    via: str = ""  # which transport answered: the session's, or native / fwlib-host on a routed machine

    @property
    def works(self) -> bool:
        return self.outcome == Outcome.OK


@dataclass(frozen=True, slots=True)
class WriteCheck:
    """Whether a write operation could work here, found out without writing anything."""

    operation: str
    transport_has_it: bool
    paired_read: str  # the read the operation relies on (read-back, type lookup, read-modify-write)
    paired_read_works: bool
    note: str = ""
    via: str = ""  # the transport that would carry it (see ProbeStep.via)

    @property
    def available(self) -> bool:
        return self.transport_has_it and self.paired_read_works


@dataclass
class ProbeReport:
    address: str
    transport: str
    connect_ms: float = 0.0
    sysinfo: SysInfo | None = None
    steps: list[ProbeStep] = field(default_factory=list)
    writes: list[WriteCheck] = field(default_factory=list)
    error: str = ""  # set when the probe could not finish (connection refused, lost, timed out)
    paths: int = 1  # CNC paths answering (edge.focas.paths)

    @property
    def model(self) -> str:
        return self.sysinfo.model_name if self.sysinfo else ""

    @property
    def complete(self) -> bool:
        return not self.error


# ---- what to try --------------------------------------------------------------------------------------

# A value that exists on every control of the family: parts count, the first axis' reference-position
# bits, the machine-position diagnosis, common macro variables, the F area (CNC -> PMC signals).
PROBE_PARAM = 6711
PROBE_AXIS_PARAM = 1815
PROBE_DIAG = 980
PROBE_MACROS = (500, 505)
PROBE_PMC = ("F", 0, 3)
PROBE_ALARM_HISTORY_DEPTH = 10


def probe_items() -> list[it.ReadItem]:
    """One of every read item (each position kind and timer kind), with arguments any control accepts."""
    items: list[it.ReadItem] = [
        it.ReadSysInfo(), it.ReadStatus(), it.ReadAlarmStatus(), it.ReadActiveAlarms(10),
        it.ReadProgramNumber(), it.ReadSequenceNumber(), it.ReadExecProgramName(), it.ReadMainProgramPath(),
        it.ReadProgramDirectory(1, 5), it.ReadFeed(), it.ReadSpindleSpeed(), it.ReadSpindleLoad(),
    ]
    items += [it.ReadPositions(kind) for kind in it.POSITION_KINDS]
    items += [
        it.ReadAxisNames(), it.ReadSpindleNames(), it.ReadServoMeter(), it.ReadControlledAxes(2),
        it.ReadControlledAxes(1), it.ReadParams(PROBE_PARAM, PROBE_PARAM),
        it.ReadParams(PROBE_AXIS_PARAM, PROBE_AXIS_PARAM, 1), it.ReadDiag(PROBE_DIAG, PROBE_DIAG, 1),
        it.ReadMacros(*PROBE_MACROS), it.ReadPmc(*PROBE_PMC, PmcType.BYTE), it.ReadClock(),
    ]
    items += [it.ReadTimer(kind) for kind in range(5)]
    items += [it.ReadToolOffsets(kind, 1, 1) for kind in range(len(it.TOOL_OFFSET_KINDS))]
    items += [it.ReadWorkOffsets(1), it.ReadModalGCodes(), it.ReadToolNumber()]
    items.append(it.ReadOperatorMessages())
    items.append(it.ReadPathStatus(2))
    items.append(it.ReadAlarmHistory(PROBE_ALARM_HISTORY_DEPTH))
    return items


def describe_arguments(item: it.ReadItem) -> str:
    match item:
        case it.ReadParams(first=first, last=last, axis=axis) | it.ReadDiag(first=first, last=last, axis=axis):
            numbers = str(first) if first == last else f"{first}..{last}"
            return f"{numbers} axis {axis}"
        case it.ReadMacros(first=first, last=last):
            return f"#{first}..#{last}"
        case it.ReadPmc(area=area, start=start, end=end, data_type=data_type):
            return f"{area}{start}..{area}{end} {data_type.name.lower()}"
        case it.ReadPositions(kind=kind):
            return kind
        case it.ReadToolOffsets(kind=kind, first=first, count=count):
            return f"{it.TOOL_OFFSET_KINDS[kind]} {first}..{first + count - 1}"
        case it.ReadPathStatus(path=path):
            return f"path {path}"
        case it.ReadWorkOffsets(number=number):
            return f"G{it.WORK_OFFSET_FIRST_G + number - 1}" if number else "external"
        case it.ReadTimer(kind=kind):
            return f"kind {kind}"
        case it.ReadControlledAxes(what=what):
            return "axes" if what == 2 else "spindles" if what == 1 else f"what {what}"
        case it.ReadActiveAlarms(max_count=count) | it.ReadAlarmHistory(depth=count):
            return f"up to {count}"
        case it.ReadProgramDirectory(start=start, count=count):
            return f"from {start}, {count}"
    return ""


def summarize(value: Any, limit: int = 60) -> str:
    """A value in one short line for the table."""
    if isinstance(value, list):
        text = f"{len(value)} item(s)" + (f": {_short(value[0])}" if value else "")
        if len(value) > 1:
            text += ", ..."
    else:
        text = _short(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _short(value: Any) -> str:
    if isinstance(value, ParamRecord):
        shown = value.values if len(value.values) > 1 else value.value
        return f"{value.number}/{value.axis} type {value.type} = {shown}"
    if isinstance(value, float):
        return f"{value:g}"
    if hasattr(value, "isoformat"):
        return str(value.isoformat())
    return str(value)


# ---- running it -----------------------------------------------------------------------------------------


def _native_commands(cnc: CncSession, item: it.ReadItem) -> str:
    """The native command code(s) an item goes out as; '' for other transports."""
    context = getattr(cnc, "context", None)
    if context is None:
        return ""
    from edge.focas.native import plan_item

    plan = plan_item(item, context)
    return "+".join(f"0x{function.command:02x}" for function, _ in plan.calls)


def _step(item: it.ReadItem, result: Any, rtt_ms: float | None, command: str) -> ProbeStep:
    step = ProbeStep(item.operation, describe_arguments(item), Outcome.OK, rtt_ms, command)
    if isinstance(result, CncError):
        available = result.code not in (EW_FUNC, EW_NOOPT)
        return replace(step, outcome=Outcome.CNC_ERROR if available else Outcome.NOT_AVAILABLE,
                       ew_code=result.code, ew_name=result.name, detail=str(result))
    if isinstance(result, NotSupported):
        return replace(step, outcome=Outcome.NOT_SUPPORTED, rtt_ms=None, detail=result.reason)
    if isinstance(result, FocasError):
        return replace(step, outcome=Outcome.FAILED, detail=str(result))
    return replace(step, detail=summarize(result))


def answered_by(cnc: CncSession, operation: str) -> str:
    """The transport an operation goes to: per function on a routed machine (fwlib_host), else the one."""
    route = getattr(cnc, "route", None)
    if route is None:
        return cnc.transport
    return str(route(operation) or "-")


async def _try(cnc: CncSession, item: it.ReadItem) -> ProbeStep:
    command = _native_commands(cnc, item)
    started = time.perf_counter()
    (result,) = await cnc.batch([item])
    rtt_ms = round((time.perf_counter() - started) * 1000, 2)
    step = _step(item, result, rtt_ms, command)  # NotSupported answers locally: its rtt is None
    return replace(step, via=answered_by(cnc, item.operation))


async def _try_other_record_form(cnc: CncSession, items: Sequence[it.ReadItem]) -> list[ProbeStep]:
    """Native only: parameter/diagnosis reads in the slot form sysinfo did NOT choose."""
    context = getattr(cnc, "context", None)
    if context is None:
        return []
    from edge.focas.values import SlotForm

    other = SlotForm.FOUR_BYTE if context.slot_form is SlotForm.SCALED else SlotForm.SCALED
    steps = []
    try:
        cnc.context = replace(context, slot_form=other)  # type: ignore[attr-defined]
        for item in items:
            step = await _try(cnc, item)
            steps.append(replace(step, function=f"{step.function} ({int(other)}-byte form)"))
    finally:
        cnc.context = context  # type: ignore[attr-defined]
    return steps


def check_writes(cnc: CncSession, steps: Sequence[ProbeStep]) -> list[WriteCheck]:
    works = {step.function for step in steps if step.works}
    can = cnc.capabilities.can
    checks = [
        WriteCheck("write_macro", can("write_macro"), "ReadMacros", "ReadMacros" in works),
        WriteCheck("write_pmc", can("write_pmc"), "ReadPmc", "ReadPmc" in works,
                   "bit writes are read-modify-write of the byte"),
        WriteCheck("write_param", can("write_param"), "ReadParams", "ReadParams" in works,
                   "the CNC also needs its parameter-write switch (PWE) on"),
        WriteCheck("set_clock", can("set_clock"), "ReadClock", "ReadClock" in works,
                   "time of day only on the native transport"),
    ]
    return [replace(check, via=answered_by(cnc, check.operation)) for check in checks]


async def probe(cnc: CncSession, address: str) -> ProbeReport:
    """Connect, identify, try every function once; the session is closed afterwards."""
    report = ProbeReport(address=address, transport=cnc.transport)
    started = time.perf_counter()
    try:
        report.sysinfo = await cnc.connect()
    except FocasError as exc:
        report.error = str(exc)
        return report
    report.connect_ms = round((time.perf_counter() - started) * 1000, 2)
    items = probe_items()
    try:
        report.paths = await path_count(cnc)
        for item in items:
            report.steps.append(await _try(cnc, item))
        record_reads = [i for i in items if isinstance(i, it.ReadParams | it.ReadDiag)]
        report.steps += await _try_other_record_form(cnc, record_reads)
    except FocasError as exc:  # ConnectionLost, FocasTimeout, ProtocolError: the session is gone
        report.error = f"lost the CNC during the probe: {exc}"
    finally:
        report.writes = check_writes(cnc, report.steps)
        await cnc.close()
    return report


# ---- output ---------------------------------------------------------------------------------------------


def report_json(report: ProbeReport) -> dict[str, Any]:
    info = report.sysinfo
    return {
        "address": report.address,
        "transport": report.transport,
        "complete": report.complete,
        "error": report.error or None,
        "connect_ms": report.connect_ms,
        "cnc": None if info is None else {
            "model": info.model_name, "cnc_type": info.cnc_type.strip(), "mt_type": info.mt_type.strip(),
            "series": info.series, "version": info.version, "max_axis": info.max_axis,
            "axes": info.axes, "record_form": "8-byte (0x8d/0x93)" if info.is_30i_style else "4-byte (0x0e/0x30)",
            "paths": report.paths,
        },
        "functions": [
            {"function": s.function, "arguments": s.arguments, "command": s.command or None,
             "outcome": s.outcome, "rtt_ms": s.rtt_ms, "ew_code": s.ew_code, "ew_name": s.ew_name or None,
             "detail": s.detail, "via": s.via}
            for s in report.steps
        ],
        "writes": [
            {"operation": w.operation, "available": w.available, "transport_has_it": w.transport_has_it,
             "paired_read": w.paired_read, "paired_read_works": w.paired_read_works, "note": w.note,
             "tried": False, "via": w.via}
            for w in report.writes
        ],
    }


def report_lines(report: ProbeReport) -> list[str]:
    lines = [f"CNC {report.address} over {report.transport}"]
    info = report.sysinfo
    if info is not None:
        form = "8-byte records (0x8d/0x93)" if info.is_30i_style else "4-byte records (0x0e/0x30)"
        lines.append(f"  model {info.model_name}  series {info.series}  version {info.version}  "
                     f"max_axis {info.max_axis}  axes {info.axes}  {form}  paths {report.paths}")
        lines.append(f"  connect {report.connect_ms:.1f} ms")
    if report.steps:
        lines.append("")
        rows = [(s.function, s.arguments, s.command, s.outcome, _rtt(s.rtt_ms), _answer(s)) for s in report.steps]
        head = ("function", "arguments", "cmd", "outcome", "rtt", "answer")
        widths = [max(len(r[i]) for r in [head, *rows]) for i in range(5)]
        for row in [head, *rows]:
            lines.append("  " + "  ".join(f"{cell:<{widths[i]}}" for i, cell in enumerate(row[:5]))
                         + "  " + row[5])
    if report.writes:
        lines.append("")
        lines.append("  writes (checked, never sent):")
        for w in report.writes:
            verdict = "available" if w.available else "not available"
            why = [] if w.transport_has_it else [f"the {report.transport} transport has no wire form"]
            if not w.paired_read_works:
                why.append(f"{w.paired_read} does not work here")
            note = "; ".join(why) or w.note
            via = f"[{w.via}] " if w.via in ROUTES else ""
            lines.append(f"    {w.operation:<12} {verdict:<14} {via}{note}".rstrip())
    if report.steps:
        ok = sum(1 for s in report.steps if s.works)
        lines.append("")
        lines.append(f"  {ok} of {len(report.steps)} function(s) answered with data")
    if report.error:
        lines.append(f"  PROBE INCOMPLETE: {report.error}")
    return lines


def _rtt(rtt_ms: float | None) -> str:
    return "-" if rtt_ms is None else f"{rtt_ms:.1f} ms"


def _answer(step: ProbeStep) -> str:
    answer = f"{step.ew_name} ({step.ew_code})" if step.ew_name else step.detail
    return f"[{step.via}] {answer}" if step.via in ROUTES else answer
