"""How each kind of write target is read, written and compared, over one CncSession.

The session already holds the rules that must hold on every transport (PMC chunking over 32 bytes,
read-modify-write of bits under a per-byte lock, bit parameters likewise, the scaled macro form); this
module only picks the right call and says what "the target holds the requested value" means.
"""

from __future__ import annotations

import math
from typing import Any

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.requests import WriteOp, pmc_bytes
from edge.command.signedness import PARAM_READINGS
from edge.focas import items as it
from edge.focas.model import ParamRecord, ParamType, PmcType
from edge.focas.packed import to_scaled
from edge.focas.session import CncSession
from edge.focas.targets import MacroTarget, ParamTarget, PmcTarget, WritableTarget
from edge.focas.values import ALL_AXES

INTEGER_PMC_TYPES = (PmcType.BYTE, PmcType.WORD, PmcType.LONG)


def read_item(target: WritableTarget) -> it.ReadItem:
    """The read that shows what `target` holds (a bit: its byte or its parameter)."""
    if isinstance(target, MacroTarget):
        return it.ReadMacros(target.first, target.last)
    if isinstance(target, PmcTarget):
        return it.ReadPmc(target.area, target.start, target.end, target.data_type)
    return it.ReadParams(target.first, target.first, target.axis)


def current_value(target: WritableTarget, result: Any) -> object:
    """What the target holds, from the result of read_item(target), in the shape a write takes."""
    if isinstance(target, MacroTarget):
        return result[0]
    if isinstance(target, PmcTarget):
        if target.bit is not None:
            return bool((int(result[0]) >> target.bit) & 1)
        return result[0] if len(result) == 1 else list(result)
    record = param_record(target, result)
    if target.bit is not None:
        return bool((int(record.value or 0) >> target.bit) & 1)
    return record.value


def param_record(target: ParamTarget, result: Any) -> ParamRecord:
    records = [r for r in result if isinstance(r, ParamRecord) and r.number == target.first]
    if not records:
        raise CommandRefused(ErrorCode.OUT_OF_RANGE, f"{target}: the CNC did not answer parameter {target.first}")
    return records[0]


def check_param(op: WriteOp, record: ParamRecord) -> None:
    """The value must fit the parameter's type as the CNC reports it; a per-axis one needs its axis."""
    target = op.target
    assert isinstance(target, ParamTarget)
    if record.axis == ALL_AXES and target.axis == 0:
        raise CommandRefused(ErrorCode.INVALID_TARGET, f"{target}: parameter {target.first} is per axis; "
                             f"address one axis, e.g. param:{target.first}/1")
    if target.bit is not None:
        if record.type != ParamType.BIT:
            raise CommandRefused(ErrorCode.WRONG_TYPE, f"{target}: parameter {target.first} is "
                                 f"{_type_name(record.type)}, not a bit parameter; write the whole value")
        return
    value = op.value
    assert isinstance(value, int | float) and not isinstance(value, bool)
    if record.type == ParamType.REAL:
        return
    reading = PARAM_READINGS.get(ParamType(record.type)) if record.type in tuple(ParamType) else None
    if reading is None:
        raise CommandRefused(ErrorCode.WRONG_TYPE, f"{target}: unknown parameter type {record.type}")
    kind = f"{target}: parameter {target.first} is {_type_name(record.type)}"
    if float(value) != int(value):
        raise CommandRefused(ErrorCode.WRONG_TYPE, f"{kind}; {value} is not an integer")
    low, high = reading.accepted
    if not low <= int(value) <= high:
        raise CommandRefused(ErrorCode.WRONG_TYPE, f"{kind}; {value} is outside {low}..{high}")
    if op.bounded and reading.is_other(int(value)):
        raise CommandRefused(ErrorCode.OUT_OF_BOUNDS, f"{kind} ({reading.describe()}); {value} would be held as "
                             f"{reading.held(int(value))}, and a bounded allow rule takes values in that reading only")


def _type_name(ptype: int) -> str:
    try:
        return ParamType(ptype).name.lower().replace("_", "-")
    except ValueError:
        return f"type {ptype}"


async def apply(session: CncSession, op: WriteOp) -> None:
    """Send `op` through the session call for its kind."""
    await write_target(session, op.target, op.value)


async def write_target(session: CncSession, target: WritableTarget, value: object) -> None:
    """One write through the session call for its target kind (the CLI's `write` uses it too).

    PMC ranges take their bytes, or element values that are packed per the target's data type.
    """
    if isinstance(target, MacroTarget):
        assert isinstance(value, float)
        await session.write_macro(target.first, value)
    elif isinstance(target, PmcTarget) and target.bit is not None:
        await session.write_pmc_bit(target.area, target.start, target.bit, bool(value))
    elif isinstance(target, PmcTarget):
        assert isinstance(value, bytes | tuple)
        data = value if isinstance(value, bytes) else pmc_bytes(target, value)
        await session.write_pmc(target.area, target.start, data)
    elif target.bit is not None:
        await session.write_param_bit(target.first, target.bit, bool(value), axis=target.axis)
    else:
        assert isinstance(value, int | float)
        await session.write_param(target.first, value, axis=target.axis)


def holds(op: WriteOp, current: object) -> bool:
    """Whether `current` (as current_value gives it) is what `op` wrote."""
    value = op.value
    if isinstance(value, bool):
        return current is value
    if isinstance(value, tuple):
        values = current if isinstance(current, list) else [current]
        return len(values) == len(value) and all(
            _same_element(op.target, c, float(w)) for c, w in zip(values, value, strict=True))
    if not isinstance(current, int | float):
        return False
    if isinstance(op.target, MacroTarget):
        return _close(float(current), expected_macro(value))
    return _close(float(current), float(value))


def expected_macro(value: float) -> float:
    """The value a macro holds after writing `value`: the scaled form rounds digits beyond 32 bits."""
    try:
        mantissa, decimals = to_scaled(value)
    except Exception:  # a value too large for the scaled form goes as a double
        return value
    return mantissa / 10**decimals


def _same_element(target: WritableTarget, current: object, written: float) -> bool:
    """PMC integers compare as bytes (0xFF == -1 in a byte); floats as float32/64 round trip."""
    if not isinstance(current, int | float) or not isinstance(target, PmcTarget):
        return False
    if target.data_type in INTEGER_PMC_TYPES:
        mask = (1 << (8 * target.data_type.width)) - 1
        return (int(current) & mask) == (int(written) & mask)
    return _close(float(current), written, rel=1e-6)


def _close(a: float, b: float, rel: float = 1e-9) -> bool:
    return math.isclose(a, b, rel_tol=rel, abs_tol=1e-9)
