"""How each transport-neutral read item becomes native subpackets, and how their answers become its value.

Sans-IO: `plan_item` turns a ReadItem into one ItemPlan (its request subpackets and a combiner);
`item_result` turns the matching response subpackets back into the item's value or its own error.
Most items are one subpacket; the clock is two (date and time) in the same PDU.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import date, datetime, time
from typing import Any

from edge.focas import functions as fn
from edge.focas import items as it
from edge.focas.errors import FocasError, NotSupported, OutOfRange, ProtocolError, cnc_error
from edge.focas.frame import Answer, RequestSubpacket, ResponseSubpacket
from edge.focas.function_entry import Context, Function, PayloadDecoder
from edge.focas.values import SlotForm

Combiner = Callable[[list[Any]], Any]


def first_value(values: list[Any]) -> Any:
    """The combiner of a one-call item: that call's value (the client inlines this case)."""
    return values[0]


def combine_clock(values: list[Any]) -> datetime:
    day, clock = values
    assert isinstance(day, date) and isinstance(clock, time)
    return datetime.combine(day, clock)


_CLOCK_FIELDS = struct.Struct(">3h")  # year, month, day (the date call) or hour, minute, second (the time call)


def clock_value(day: Answer, clock: Answer) -> datetime | None:
    """The clock item's value from its two answers in one step: the date fields of the first payload and the
    time fields of the second, as one datetime (what item_value makes of them through a date, a time and
    combine_clock; the client asks it at every new CNC second, every tick at 1 Hz). None for anything else (an
    error code, a payload of another size, no such date or time): item_value then gives that answer's error."""
    if day[0] or clock[0] or len(day[2]) != fn.CLOCK_PAYLOAD or len(clock[2]) != fn.CLOCK_PAYLOAD:
        return None
    try:
        return datetime(*_CLOCK_FIELDS.unpack_from(day[2]), *_CLOCK_FIELDS.unpack_from(clock[2], 6))
    except ValueError:
        return None


@dataclass(frozen=True, slots=True)
class ItemPlan:
    """The subpackets one item needs and how to combine their decoded values; or why it cannot be read."""

    item: it.ReadItem
    calls: tuple[tuple[Function, RequestSubpacket], ...] = ()
    combine: Combiner = first_value
    error: FocasError | None = None

    @property
    def requests(self) -> list[RequestSubpacket]:
        return [req for _, req in self.calls]


NO_WIRE_CODE = "no public FOCAS/Ethernet wire code is known for it (see docs/protocol.md)"

_SIMPLE: dict[type[it.ReadItem], Function] = {
    it.ReadSysInfo: fn.SYSINFO,
    it.ReadStatus: fn.STATINFO,
    it.ReadAlarmStatus: fn.ALARM_STATUS,
    it.ReadProgramNumber: fn.PROGRAM_NUMBER,
    it.ReadSequenceNumber: fn.SEQUENCE_NUMBER,
    it.ReadExecProgramName: fn.EXEC_PROGRAM_NAME,
    it.ReadMainProgramPath: fn.MAIN_PROGRAM_PATH,
    it.ReadFeed: fn.ACTUAL_FEED,
    it.ReadSpindleSpeed: fn.ACTUAL_SPINDLE_SPEED,
    it.ReadAxisNames: fn.AXIS_NAMES,
    it.ReadSpindleNames: fn.SPINDLE_NAMES,
    it.ReadOperatorMessages: fn.OPERATOR_MESSAGES,
}

# Item classes the native transport answers (ReadAlarmHistory has no public wire code).
SUPPORTED_ITEMS: frozenset[str] = frozenset(
    {cls.__name__ for cls in _SIMPLE}
    | {"ReadActiveAlarms", "ReadProgramDirectory", "ReadSpindleLoad", "ReadPositions", "ReadServoMeter",
       "ReadControlledAxes", "ReadParams", "ReadDiag", "ReadMacros", "ReadPmc", "ReadClock", "ReadTimer",
       "ReadToolOffsets", "ReadPathStatus"}
)

SPINDLE_LOAD_ARGS = (4, -1)  # HslCommunication: kind 4 = load, all spindles
SERVO_METER_TYPE = 1  # as in the pyfanuc multi-subpacket capture
PROGRAM_DIRECTORY_TYPE = 2  # pyfanuc listprog (HslCommunication sends 0)


def pmc_byte_end(start: int, end: int, width: int) -> int:
    """Inclusive last byte address covering whole elements: a word read of D2204..D2204 becomes ..2205."""
    count = max(1, -(-(end - start + 1) // width))
    return start + width * count - 1


def _one(item: it.ReadItem, function: Function, *args: int, path: int) -> ItemPlan:
    return ItemPlan(item, ((function, function.request(*args, path=path)),))


SHARED_PLANS_LIMIT = 4096  # (item, context, path) triples; a fleet of a few models plans a few hundred
_SHARED_PLANS: dict[tuple[it.ReadItem, Context, int], ItemPlan] = {}


def shared_plan_item(item: it.ReadItem, ctx: Context, path: int = 1) -> ItemPlan:
    """plan_item, one plan (and its request subpackets) for every session of the process that asks for the same
    item of the same kind of control: a plan is pure and immutable, and a copy per machine was ~12 kB each at
    1,000 machines. A plan that carries an error is not shared (an exception object gains a traceback when
    raised)."""
    key = (item, ctx, path)
    plan = _SHARED_PLANS.get(key)
    if plan is None:
        plan = plan_item(item, ctx, path)
        if plan.error is None:
            if len(_SHARED_PLANS) >= SHARED_PLANS_LIMIT:
                _SHARED_PLANS.clear()
            _SHARED_PLANS[key] = plan
    return plan


def plan_item(item: it.ReadItem, ctx: Context, path: int = 1) -> ItemPlan:
    """The native subpackets for `item` (errors in the item itself become the plan's error)."""
    try:
        return _plan(item, ctx, path)
    except ValueError as exc:
        return ItemPlan(item, error=OutOfRange(3, item.operation, message=str(exc)))


def _plan(item: it.ReadItem, ctx: Context, path: int) -> ItemPlan:
    simple = _SIMPLE.get(type(item))
    if simple is not None:
        return _one(item, simple, path=path)
    records_8 = ctx.slot_form is SlotForm.SCALED
    match item:
        case it.ReadActiveAlarms(max_count=count):
            return _one(item, fn.ALARM_MESSAGES, -1, count, 2, fn.ALARM_TEXT_LEN, path=path)
        case it.ReadProgramDirectory(start=start, count=count):
            return _one(item, fn.PROGRAM_DIRECTORY, start, count, PROGRAM_DIRECTORY_TYPE, path=path)
        case it.ReadSpindleLoad():
            return _one(item, fn.SPINDLE_LOAD, *SPINDLE_LOAD_ARGS, path=path)
        case it.ReadPositions(kind=kind):
            return ItemPlan(item, ((fn.POSITIONS, fn.positions_request(kind, path)),))
        case it.ReadServoMeter():
            return _one(item, fn.SERVO_METER, SERVO_METER_TYPE, path=path)
        case it.ReadControlledAxes(what=what):
            return _one(item, fn.CONTROLLED_AXES, what, path=path)
        case it.ReadParams(first=first, last=last, axis=axis):
            function = fn.READ_PARAMS_8 if records_8 else fn.READ_PARAMS_4
            return _one(item, function, first, last, axis, path=path)
        case it.ReadDiag(first=first, last=last, axis=axis):
            function = fn.READ_DIAG_8 if records_8 else fn.READ_DIAG_4
            return _one(item, function, first, last, axis, path=path)
        case it.ReadMacros(first=first, last=last):
            if last < first:
                raise ValueError(f"macro range #{first}..#{last} is empty")
            return _one(item, fn.READ_MACROS, first, last, path=path)
        case it.ReadPmc(area=area, start=start, end=end, data_type=data_type):
            if end < start:
                raise ValueError(f"PMC range {area}{start}..{area}{end} is empty")
            last = pmc_byte_end(start, end, data_type.width)
            return _one(item, fn.READ_PMC, start, last, fn.pmc_adr_type(area), int(data_type), path=path)
        case it.ReadClock():
            calls = tuple((fn.READ_CLOCK, fn.READ_CLOCK.request(part, path=path))
                          for part in (fn.CLOCK_DATE, fn.CLOCK_TIME))
            return ItemPlan(item, calls, combine_clock)
        case it.ReadTimer(kind=kind):
            return _one(item, fn.READ_TIMER, kind, path=path)
        case it.ReadPathStatus(path=other):
            return _one(item, fn.STATINFO, path=other)
        case it.ReadToolOffsets(kind=kind, first=first, count=count):
            if count < 1 or not 0 <= kind < len(it.TOOL_OFFSET_KINDS):
                raise ValueError(f"tool offsets: kind {kind} (0..3) and count {count} (>= 1)")
            return _one(item, fn.TOOL_OFFSETS, first, first + count - 1, kind, path=path)
        case it.ReadAlarmHistory() | it.ReadWorkOffsets() | it.ReadModalGCodes() | it.ReadToolNumber():
            return ItemPlan(item, error=NotSupported(item.operation, NO_WIRE_CODE))
    return ItemPlan(item, error=NotSupported(item.operation, "the native transport does not know this item"))


def item_result(plan: ItemPlan, answers: Sequence[ResponseSubpacket], ctx: Context) -> Any:
    """The item's value, or the FocasError this item alone got (CNC return code or a bad payload)."""
    return item_value(plan, [(sub.rc, sub.detail, sub.payload) for sub in answers], 0, ctx)


def item_value(plan: ItemPlan, answers: Sequence[Answer], offset: int, ctx: Context) -> Any:
    """As item_result, from the (rc, detail, payload) answers of a whole PDU, this item's at `offset`."""
    if plan.error is not None:
        return plan.error
    calls = plan.calls
    if len(answers) < offset + len(calls):
        return ProtocolError(f"{plan.item.operation}: {len(calls)} answer(s) expected at {offset}, "
                             f"{len(answers)} in the PDU")
    values = []
    for index, (function, req) in enumerate(calls):
        value = call_value(function.decode_payload, function.name, req, answers[offset + index], ctx)
        if isinstance(value, FocasError):
            return value
        values.append(value)
    try:
        return plan.combine(values)
    except FocasError as exc:
        return exc


def call_value(decode: PayloadDecoder, name: str, req: RequestSubpacket, answer: Answer, ctx: Context) -> Any:
    """One call's decoded value, or the FocasError of its return code or of a bad payload."""
    rc, detail, payload = answer
    if rc != 0:
        return cnc_error(rc, name, detail)
    try:
        return decode(payload, req, ctx)
    except FocasError as exc:
        return exc
