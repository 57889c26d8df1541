"""Value encodings inside FOCAS payloads, sans-IO: scaled numbers, PMC elements, parameter records.

The 8-byte scaled value (macros, positions, feeds, 30i-form parameter slots)::

    i32 mantissa | 00 | base (0A = 10, 02 = 2) | i16 exponent      value = mantissa / base ** exponent

with exponent bytes ``FF FF`` meaning "no value" (a vacant macro, an empty axis slot). Parameter and
diagnosis records are ``i32 number | i16 axis | i16 type | max_axis slots``; a slot is 4 bytes on
16i/0i-style controls (0x0e/0x30) and one 8-byte scaled value on 30i-style controls (0x8d/0x93).
Decoders raise ProtocolError only; encoders raise ValueError for values the wire cannot carry.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from decimal import Decimal

from edge.focas.errors import ProtocolError
from edge.focas.model import ParamRecord, ParamType, PmcType

SCALED_SIZE = 8
NO_VALUE = b"\xff\xff\xff\xff\x00\x0a\xff\xff"
SCALED_LAYOUT = struct.Struct(">iBBh")
_I32_MIN, _I32_MAX = -(2**31), 2**31 - 1
# Published captures only show exponents 0..8; a wider band still decodes, beyond it a slot is garbage.
MAX_EXPONENT = 64
MAX_ENCODE_EXPONENT = 9

ScaledValue = float | None


# ---- 8-byte scaled values -----------------------------------------------------------------------------


def decode_scaled(data: bytes, offset: int = 0, *, strict: bool = True) -> ScaledValue:
    """One 8-byte scaled value at `offset`; None for the FF FF sentinel.

    strict=False turns an impossible base/exponent into None instead of an error: unused record slots
    may hold garbage.
    """
    if len(data) < offset + SCALED_SIZE:
        raise ProtocolError(f"expected an 8-byte scaled value at offset {offset}, "
                            f"got {max(0, len(data) - offset)} bytes")
    mantissa, _zero, base, exponent = SCALED_LAYOUT.unpack_from(data, offset)
    if exponent == -1:
        return None
    if exponent == 0:  # no scaling: the base does not matter (an all-zero slot reads as 0)
        return float(mantissa)
    if base not in (2, 10) or not -MAX_EXPONENT <= exponent <= MAX_EXPONENT:
        if not strict:
            return None
        raise ProtocolError(f"scaled value at offset {offset}: expected base 10 or 2 and exponent within "
                            f"±{MAX_EXPONENT}, got base {base} exponent {exponent} "
                            f"({bytes(data[offset : offset + 8]).hex()})")
    if exponent >= 0:
        return mantissa / base**exponent  # int/int true division: correctly rounded
    return float(mantissa * base ** (-exponent))


_POWERS_OF_TEN = tuple(10**exponent for exponent in range(MAX_EXPONENT + 1))


def decode_scaled_list(payload: bytes, *, strict: bool = True) -> list[ScaledValue]:
    if len(payload) % SCALED_SIZE:
        raise ProtocolError(f"expected a multiple of 8 bytes of scaled values, got {len(payload)}")
    # The common shapes (no scaling; a positive power of ten; vacant) decoded inline, all at one unpack: a poll
    # tick decodes every axis position this way. Anything else goes through decode_scaled and its checks.
    values: list[ScaledValue] = []
    append = values.append
    for index, (mantissa, _zero, base, exponent) in enumerate(SCALED_LAYOUT.iter_unpack(payload)):
        if exponent == 0:
            append(float(mantissa))
        elif base == 10 and 0 < exponent <= MAX_EXPONENT:
            append(mantissa / _POWERS_OF_TEN[exponent])  # the same int as 10**exponent, not computed per value
        elif exponent == -1:  # the FF FF sentinel (a vacant macro): None, as decode_scaled says
            append(None)
        else:
            append(decode_scaled(payload, index * SCALED_SIZE, strict=strict))
    return values


def encode_scaled(value: float | None, exponent: int | None = None) -> bytes:
    """Base-10 scaled value; by default the smallest exponent that carries the decimal exactly.

    A value with more digits than an i32 mantissa holds is rounded at the largest exponent that fits.
    `exponent` forces one (HslCommunication always writes 3).
    """
    if value is None:
        return NO_VALUE
    if exponent is None:
        quick = _plain_decimal(value)
        if quick is not None:
            return quick
    return _encode_decimal(value, exponent)


def _encode_decimal(value: float, exponent: int | None) -> bytes:
    """encode_scaled the general way: Decimal arithmetic over the candidate exponents."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"cannot encode {value} as a scaled value")
    exact = Decimal(repr(value)) if isinstance(value, float) else Decimal(value)
    candidates = [exponent] if exponent is not None else list(range(MAX_ENCODE_EXPONENT + 1))
    best: tuple[int, int] | None = None
    for exp in candidates:
        scaled = exact.scaleb(exp)
        mantissa = int(scaled.to_integral_value())
        if not _I32_MIN <= mantissa <= _I32_MAX:
            break
        best = (mantissa, exp)
        if scaled == mantissa:
            break
    if best is None:
        raise ValueError(f"{value} does not fit a scaled value (i32 mantissa, exponent "
                         f"{candidates[0]}..{candidates[-1]})")
    mantissa, exp = best
    return SCALED_LAYOUT.pack(mantissa, 0, 10, exp)


def _plain_decimal(value: float) -> bytes | None:
    """The smallest-exponent encoding without Decimal, when the value's shortest repr is a plain decimal.

    The smallest exponent at which Decimal(repr(value)) is an integer is the count of fraction digits
    (trailing zeros dropped) of a repr without an exponent. When that is at most MAX_ENCODE_EXPONENT and
    the digits fit an i32, the digits are the mantissa. Anything else (1e-05, inf, nan, big ints): None.
    """
    if value.__class__ is float:
        text = repr(value)
        if "e" in text or "n" in text:
            return None
        whole, _, fraction = text.partition(".")
        fraction = fraction.rstrip("0")
        mantissa = int(whole + fraction)
        if len(fraction) <= MAX_ENCODE_EXPONENT and _I32_MIN <= mantissa <= _I32_MAX:
            return SCALED_LAYOUT.pack(mantissa, 0, 10, len(fraction))
    elif value.__class__ is int and _I32_MIN <= value <= _I32_MAX:
        return SCALED_LAYOUT.pack(value, 0, 10, 0)
    return None


def encode_scaled_list(values: Sequence[float | None]) -> bytes:
    return b"".join(encode_scaled(v) for v in values)


# ---- PMC elements -------------------------------------------------------------------------------------

_PMC_FORMATS: dict[PmcType, str] = {t: t.struct_code for t in PmcType}  # a dict: this is the poll path


def pmc_type(code: int) -> PmcType:
    try:
        return PmcType(code)
    except ValueError:
        raise ProtocolError(f"expected a PMC data type in {[int(t) for t in PmcType]}, got {code}") from None


def decode_pmc(payload: bytes, data_type: PmcType) -> list[int | float]:
    width = data_type.width
    if len(payload) % width:
        raise ProtocolError(f"PMC {data_type.name.lower()} data: expected a multiple of {width} bytes, "
                            f"got {len(payload)}")
    count = len(payload) // width
    return list(struct.unpack(f">{count}{_PMC_FORMATS[data_type]}", payload))


def encode_pmc(values: Sequence[int | float], data_type: PmcType) -> bytes:
    try:
        return struct.pack(f">{len(values)}{_PMC_FORMATS[data_type]}", *values)
    except struct.error as exc:
        raise ValueError(f"cannot encode {list(values)} as PMC {data_type.name.lower()}: {exc}") from exc


# ---- parameter / diagnosis records --------------------------------------------------------------------


class SlotForm(enum.IntEnum):
    """Width of one per-axis slot in a parameter/diagnosis record."""

    FOUR_BYTE = 4  # 0x0e / 0x30: 16i, 18i, 21i, 0i, 160i
    SCALED = 8  # 0x8d / 0x93: 30i, 31i, 32i (and 0i-F)


RECORD_HEAD_LAYOUT = struct.Struct(">ihh")
ALL_AXES = -1  # the FOCAS axis argument that reads or writes every axis at once


def record_stride(max_axis: int, form: SlotForm) -> int:
    return RECORD_HEAD_LAYOUT.size + max_axis * int(form)


def _decode_slot4(slot: bytes, ptype: int, whole_slot: bool) -> int:
    # A parameter's bit and byte values sit in the last byte; everything else is the whole slot as i32.
    # Diagnosis records always read the whole slot: their type codes do not give the size (model.py).
    if not whole_slot and ptype in (ParamType.BIT, ParamType.BYTE):
        return slot[3]
    return int(struct.unpack(">i", slot)[0])


def _decode_slot8(data: bytes, offset: int, ptype: int, whole_slot: bool) -> int | float | None:
    value = decode_scaled(data, offset, strict=False)
    if value is None or (ptype == ParamType.REAL and not whole_slot):
        return value
    return int(value) if value.is_integer() else value


def decode_records(payload: bytes, max_axis: int, form: SlotForm, *,
                   whole_slots: bool = False) -> list[ParamRecord]:
    """Records as 0x0e/0x30/0x8d/0x93 answer them.

    For axis -1 every slot is returned (one per possible axis); otherwise only slot 0 is meaningful and
    the record carries that one value (the rest of the slots may be garbage). `whole_slots` (diagnosis
    records) decodes each value by the slot's size alone, whatever the record's type code says.
    """
    if max_axis < 1:
        raise ProtocolError(f"record decode needs max_axis >= 1, got {max_axis}")
    stride = record_stride(max_axis, form)
    if len(payload) % stride:
        raise ProtocolError(f"expected records of {stride} bytes (max_axis {max_axis}, {int(form)}-byte "
                            f"slots), got a {len(payload)}-byte payload")
    records = []
    for start in range(0, len(payload), stride):
        number, axis, ptype = RECORD_HEAD_LAYOUT.unpack_from(payload, start)
        slots = max_axis if axis == ALL_AXES else 1
        base = start + RECORD_HEAD_LAYOUT.size
        values: list[int | float | None] = []
        for i in range(slots):
            offset = base + i * int(form)
            if form is SlotForm.FOUR_BYTE:
                values.append(_decode_slot4(payload[offset : offset + 4], ptype, whole_slots))
            else:
                values.append(_decode_slot8(payload, offset, ptype, whole_slots))
        records.append(ParamRecord(number, axis, ptype, tuple(values)))
    return records


def _encode_slot4(value: int | float | None, ptype: int, whole_slot: bool) -> bytes:
    number = 0 if value is None else round(value)
    if not whole_slot and ptype in (ParamType.BIT, ParamType.BYTE):
        return bytes([0, 0, 0, number & 0xFF])
    if not _I32_MIN <= number <= _I32_MAX:
        raise ValueError(f"{value} does not fit a 4-byte parameter slot")
    return struct.pack(">i", number)


def encode_records(records: Sequence[ParamRecord], max_axis: int, form: SlotForm, *,
                   whole_slots: bool = False) -> bytes:
    """The payload a CNC sends for `records`; missing slots are zero (as in the 31i captures)."""
    out = bytearray()
    for record in records:
        if len(record.values) > max_axis:
            raise ValueError(f"record {record.number} has {len(record.values)} values, max_axis {max_axis}")
        out += RECORD_HEAD_LAYOUT.pack(record.number, record.axis, record.type)
        padded = list(record.values) + [0] * (max_axis - len(record.values))
        for value in padded:
            out += (_encode_slot4(value, record.type, whole_slots) if form is SlotForm.FOUR_BYTE
                    else encode_scaled(value))
    return bytes(out)


# ---- small helpers shared by function decoders --------------------------------------------------------


def c_string(raw: bytes) -> str:
    """A NUL-terminated, NUL-padded ASCII field as text (latin-1, so no byte can fail)."""
    end = raw.find(b"\x00")
    return (raw if end < 0 else raw[:end]).decode("latin-1")


def pad_c_string(text: str, size: int) -> bytes:
    raw = text.encode("latin-1")[:size]
    return raw + b"\x00" * (size - len(raw))
