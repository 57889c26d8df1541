"""What the machine is and does, on the packed surface: the small fixed reads.

Status (ODBST), identity (ODBSYS), clock, program and sequence numbers, positions, feed and speed, axis
names, timers, work offsets, modal G codes and the tool in use: each one command, one short layout.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from edge.focas.errors import ProtocolError
from edge.focas.model import ModalGCode, ProgramNumbers, StatInfo, SysInfo, TimerValue
from edge.focas.packed.commands import I16, Command, body_after_status, command_name, expect_length, unpack_exact

# ---- ODBST (0x0001) ---------------------------------------------------------------------------------
_ODBST = struct.Struct("<9h")


@dataclass(frozen=True, slots=True)
class CncStatus:
    """ODBST as the surface carries it: fwlib32.h's 9 shorts (hdck, tmmode, then StatInfo's seven)."""

    hdck: int
    tmmode: int
    aut: int
    run: int
    motion: int
    mstb: int
    emergency: int
    alarm: int
    edit: int

    def to_statinfo(self) -> StatInfo:
        return StatInfo(self.aut, self.run, self.motion, self.mstb, self.emergency, self.alarm, self.edit)

    @classmethod
    def from_statinfo(cls, stat: StatInfo, hdck: int = 0, tmmode: int = 0) -> CncStatus:
        return cls(hdck, tmmode, stat.aut, stat.run, stat.motion, stat.mstb, stat.emergency, stat.alarm,
                   stat.edit)


def encode_cncstat(status: CncStatus) -> bytes:
    return _ODBST.pack(status.hdck, status.tmmode, status.aut, status.run, status.motion, status.mstb,
                       status.emergency, status.alarm, status.edit)


def decode_cncstat(body: bytes) -> CncStatus:
    return CncStatus(*unpack_exact(_ODBST, body, "ODBST"))


def decode_cncstat_response(payload: bytes) -> CncStatus:
    return decode_cncstat(body_after_status(payload, Command.RDCNCSTAT))


# ---- ODBSYS (0x4001) -----------------------------------------------------------------------------------
_ODBSYS = struct.Struct("<hh2s2s4s4s2s")


def _ascii_field(text: str, width: int) -> bytes:
    return text.encode("ascii", errors="replace")[:width].ljust(width, b" ")


def encode_sysinfo(info: SysInfo) -> bytes:
    return _ODBSYS.pack(info.addinfo, info.max_axis, _ascii_field(info.cnc_type, 2),
                        _ascii_field(info.mt_type, 2), _ascii_field(info.series, 4),
                        _ascii_field(info.version, 4), _ascii_field(info.axes, 2))


def decode_sysinfo_response(payload: bytes) -> SysInfo:
    addinfo, max_axis, *texts = unpack_exact(_ODBSYS, body_after_status(payload, Command.SYSINFO), "ODBSYS")
    cnc_type, mt_type, series, version, axes = (bytes(t).decode("ascii", errors="replace") for t in texts)
    return SysInfo(addinfo, max_axis, cnc_type, mt_type, series, version, axes)


# ---- clock (0x4003) ------------------------------------------------------------------------------------
_CLOCK = struct.Struct("<6h")


def encode_clock(when: datetime) -> bytes:
    """The CNC's local wall-clock time as six i16: year, month, day, hour, minute, second."""
    return _CLOCK.pack(when.year, when.month, when.day, when.hour, when.minute, when.second)


def decode_clock_response(payload: bytes) -> datetime:
    fields = unpack_exact(_CLOCK, body_after_status(payload, Command.GETTIME), "cnc_gettime")
    year, month, day, hour, minute, second = fields
    try:
        return datetime(year, month, day, hour, minute, second)
    except ValueError as exc:
        raise ProtocolError(f"cnc_gettime: impossible date/time {fields}: {exc}") from None


# ---- small fixed reads (0x4005 ... 0x400C) -------------------------------------------------------------
_I32 = struct.Struct("<i")
_TWO_I32 = struct.Struct("<ii")
_F64 = struct.Struct("<d")
POSITION_CODES: dict[str, int] = {"absolute": 0, "machine": 1, "relative": 2, "distance": 3}
POSITION_KINDS_BY_CODE: dict[int, str] = {code: kind for kind, code in POSITION_CODES.items()}
AXIS_NAME_WIDTH = 4


def encode_int32(value: int) -> bytes:
    return _I32.pack(value)


def decode_int32_response(payload: bytes, command: int) -> int:
    return int(unpack_exact(_I32, body_after_status(payload, command), command_name(command))[0])


def encode_program_numbers(numbers: ProgramNumbers) -> bytes:
    return _TWO_I32.pack(numbers.running, numbers.main)


def decode_program_numbers_response(payload: bytes) -> ProgramNumbers:
    running, main = unpack_exact(_TWO_I32, body_after_status(payload, Command.RDPRGNUM), "cnc_rdprgnum")
    return ProgramNumbers(running, main)


def encode_timer(timer: TimerValue) -> bytes:
    return _TWO_I32.pack(timer.minutes, timer.msec)


def decode_timer_response(payload: bytes) -> TimerValue:
    minutes, msec = unpack_exact(_TWO_I32, body_after_status(payload, Command.RDTIMER), "cnc_rdtimer")
    return TimerValue(minutes, msec)


def encode_float(value: float | None) -> bytes:
    """f64 LE; NaN stands for "no value"."""
    return _F64.pack(math.nan if value is None else value)


def _optional_float(value: float) -> float | None:
    return None if math.isnan(value) else value


def decode_float_response(payload: bytes, command: int) -> float | None:
    return _optional_float(unpack_exact(_F64, body_after_status(payload, command), command_name(command))[0])


def encode_floats(values: Sequence[float | None]) -> bytes:
    """i16 count, then count f64 (NaN = no value): positions per axis."""
    return I16.pack(len(values)) + b"".join(encode_float(v) for v in values)


def decode_floats_response(payload: bytes, command: int) -> list[float | None]:
    body = body_after_status(payload, command)
    if len(body) < 2:
        raise ProtocolError(f"{command_name(command)}: expected an i16 count, got {len(body)} bytes")
    (count,) = I16.unpack_from(body)
    expect_length(body, 2 + _F64.size * max(count, 0), f"{command_name(command)} with {count} values")
    return [_optional_float(v) for (v,) in _F64.iter_unpack(body[2:])]


def encode_axis_names(names: Sequence[str]) -> bytes:
    """i16 count, then count 4-byte ASCII names, NUL-padded."""
    return I16.pack(len(names)) + b"".join(
        n.encode("ascii", errors="replace")[:AXIS_NAME_WIDTH].ljust(AXIS_NAME_WIDTH, b"\x00") for n in names
    )


def decode_axis_names_response(payload: bytes) -> list[str]:
    body = body_after_status(payload, Command.RDAXISNAME)
    if len(body) < 2:
        raise ProtocolError(f"cnc_rdaxisname: expected an i16 count, got {len(body)} bytes")
    (count,) = I16.unpack_from(body)
    expect_length(body, 2 + AXIS_NAME_WIDTH * max(count, 0), f"cnc_rdaxisname with {count} names")
    raw = body[2:]
    return [
        raw[i : i + AXIS_NAME_WIDTH].rstrip(b"\x00").decode("ascii", errors="replace")
        for i in range(0, len(raw), AXIS_NAME_WIDTH)
    ]


# ---- work-coordinate offsets (0x400D) ------------------------------------------------------------------
# The request is one i16 offset number (cnc_rdzofs: 0 external, 1..6 G54..G59); the answer is encode_floats'
# i16 count + one f64 per controlled axis (the library host reads IODBZOFS with type -1, every axis).


def decode_work_offsets_response(payload: bytes) -> list[float | None]:
    return decode_floats_response(payload, Command.RDZOFS)


# ---- modal G codes (0x400E) ------------------------------------------------------------------------------
# Empty request. Answer: i16 count, then count x (i16 group, 8-byte ASCII code NUL-padded): ODBGCD minus flag.
G_CODE_WIDTH = 8
_GCODE_HEAD = struct.Struct("<h")


def encode_modal_g_codes(codes: Sequence[ModalGCode]) -> bytes:
    return I16.pack(len(codes)) + b"".join(
        _GCODE_HEAD.pack(c.group) + c.code.encode("ascii", errors="replace")[:G_CODE_WIDTH].ljust(G_CODE_WIDTH, b"\x00")
        for c in codes)


def decode_modal_g_codes_response(payload: bytes) -> list[ModalGCode]:
    body = body_after_status(payload, Command.RDGCODE)
    if len(body) < 2:
        raise ProtocolError(f"cnc_rdgcode: expected an i16 count, got {len(body)} bytes")
    (count,) = I16.unpack_from(body)
    entry = _GCODE_HEAD.size + G_CODE_WIDTH
    expect_length(body, 2 + entry * max(count, 0), f"cnc_rdgcode with {count} codes")
    codes = []
    for at in range(2, len(body), entry):
        (group,) = _GCODE_HEAD.unpack_from(body, at)
        raw = body[at + _GCODE_HEAD.size : at + entry]
        codes.append(ModalGCode(group, raw.rstrip(b"\x00").decode("ascii", errors="replace")))
    return codes


# ---- T code in use (0x400F): empty request, answer i32 (encode_int32) ------------------------------------
def decode_tool_number_response(payload: bytes) -> int:
    return decode_int32_response(payload, Command.RDTOOLNUM)
