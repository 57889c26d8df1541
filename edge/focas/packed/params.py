"""Parameters and diagnosis on the packed surface: IODBPSD (0x0002 / 0x0004 read, 0x0102 write)."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from edge.focas.errors import OutOfRange, ProtocolError
from edge.focas.model import ParamRecord, ParamType
from edge.focas.packed.commands import Command, body_after_status, command_name, expect_length, unpack_exact
from edge.focas.packed.scaled import I32_MIN, from_scaled, to_scaled

# ---- IODBPSD (0x0002 / 0x0004 read, 0x0102 write) ------------------------------------------------------
# IODBPSD: i16 datano | i16 type (axis: 0 whole CNC, n axis n, -1 all axes on reads) | data.
# The data width follows the parameter type: bit/byte 1 (signed byte on the wire), word 2 (i16),
# 2-word 4 (i32), real 8 (REALPRM: i32 prm_val, i32 dec_val — our extension; the seed stops at i32).
_IODBPSD_HEAD = struct.Struct("<hh")
_PARAM_READ_REQUEST = struct.Struct("<hh")
_PARAM_TYPE = struct.Struct("<h")
_REALPRM = struct.Struct("<ii")
PARAM_WIDTHS: dict[ParamType, int] = {
    ParamType.BIT: 1,
    ParamType.BYTE: 1,
    ParamType.WORD: 2,
    ParamType.TWO_WORD: 4,
    ParamType.REAL: 8,
}
_INT_RANGES: dict[int, tuple[int, int]] = {1: (-128, 255), 2: (-(2**15), 2**16 - 1), 4: (I32_MIN, 2**32 - 1)}


def param_width(ptype: int) -> int:
    try:
        return PARAM_WIDTHS[ParamType(ptype)]
    except ValueError:
        raise OutOfRange(4, "IODBPSD", message=f"unknown parameter type {ptype}") from None


def encode_param_value(ptype: int, value: int | float, what: str = "IODBPSD") -> bytes:
    """One data slot of IODBPSD; integer types accept signed or unsigned values of their width."""
    width = param_width(ptype)
    if width == 8:
        return _REALPRM.pack(*to_scaled(value, what))
    if isinstance(value, float):
        if not value.is_integer():
            raise OutOfRange(5, what, message=f"type {ptype} parameters hold integers, got {value!r}")
        value = int(value)
    low, high = _INT_RANGES[width]
    if not low <= value <= high:
        raise OutOfRange(5, what, message=f"{value} does not fit a {width}-byte parameter ({low}..{high})")
    return (value & ((1 << (8 * width)) - 1)).to_bytes(width, "little")


def decode_param_value(ptype: int, data: bytes) -> int | float:
    """The inverse of encode_param_value; bit parameters read back unsigned (0..255)."""
    width = param_width(ptype)
    expect_length(data, width, f"IODBPSD data of type {ptype}")
    if width == 8:
        return from_scaled(*_REALPRM.unpack(data))
    return int.from_bytes(data, "little", signed=ptype != ParamType.BIT)


@dataclass(frozen=True, slots=True)
class ParamWrite:
    """A decoded 0x0102 request: the data width is all the wire says about the type."""

    number: int
    axis: int
    data: bytes

    def value_as(self, ptype: int) -> int | float:
        return decode_param_value(ptype, self.data)


def encode_param_write(number: int, axis: int, ptype: int, value: int | float) -> bytes:
    """0x0102 request: IODBPSD, data width = the parameter type's width (byte 4+1, int16 4+2, int32 4+4)."""
    return _IODBPSD_HEAD.pack(number, axis) + encode_param_value(ptype, value, "cnc_wrparam")


def decode_param_write(payload: bytes) -> ParamWrite:
    if len(payload) - _IODBPSD_HEAD.size not in (1, 2, 4, 8):
        raise ProtocolError(
            f"cnc_wrparam: expected IODBPSD of 4+1, 4+2, 4+4 or 4+8 bytes, got {len(payload)} bytes"
        )
    number, axis = _IODBPSD_HEAD.unpack_from(payload)
    return ParamWrite(number, axis, payload[_IODBPSD_HEAD.size :])


def encode_param_read(number: int, axis: int = 0) -> bytes:
    """0x0002 / 0x0004 request: i16 datano, i16 axis."""
    return _PARAM_READ_REQUEST.pack(number, axis)


def decode_param_read(payload: bytes) -> tuple[int, int]:
    number, axis = unpack_exact(_PARAM_READ_REQUEST, payload, "cnc_rdparam request")
    return number, axis


def encode_param_record(record: ParamRecord) -> bytes:
    """0x0002 / 0x0004 response body: i16 param type, then IODBPSD with one data slot per value."""
    slots = b"".join(encode_param_value(record.type, v if v is not None else 0) for v in record.values)
    return _PARAM_TYPE.pack(record.type) + _IODBPSD_HEAD.pack(record.number, record.axis) + slots


def decode_param_record(body: bytes, what: str = "cnc_rdparam") -> ParamRecord:
    head = _PARAM_TYPE.size + _IODBPSD_HEAD.size
    if len(body) < head:
        raise ProtocolError(f"{what}: expected at least {head} bytes (type + IODBPSD head), got {len(body)}")
    (ptype,) = _PARAM_TYPE.unpack_from(body)
    number, axis = _IODBPSD_HEAD.unpack_from(body, _PARAM_TYPE.size)
    if ptype not in tuple(ParamType):
        raise ProtocolError(f"{what}: parameter {number} has unknown type {ptype} (expected 0..4)")
    width = PARAM_WIDTHS[ParamType(ptype)]
    data = body[head:]
    if not data or len(data) % width:
        raise ProtocolError(
            f"{what}: parameter {number} type {ptype} needs a multiple of {width} data bytes, got {len(data)}"
        )
    values = tuple(decode_param_value(ptype, data[i : i + width]) for i in range(0, len(data), width))
    return ParamRecord(number, axis, ptype, values)


def decode_param_response(payload: bytes, command: int = Command.RDPARAM) -> ParamRecord:
    return decode_param_record(body_after_status(payload, command), command_name(command))
