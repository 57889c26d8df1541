"""The packed-buffer surface of seeds 000-002: little-endian payload codecs, sans-IO.

The surface is a language-neutral encoding that a FOCAS client and a simulator (or a bridge to the vendor
library) speak over IPC. It is *not* the native FOCAS/Ethernet wire format: every integer is little-endian
and each FOCAS call has a stable command id from an append-only table. Framing (length prefix, command
echo) lives in :mod:`edge.focas.packed_frame`; this module only turns payloads into typed values and back.

Both directions are here (client requests/decoders and the simulator's request decoders/response
encoders), so client and simulator cannot disagree about a layout; every writer is the matching reader
reversed. docs/packed-protocol.md has a byte table for every layout.

Reads defined by this project (the seed only names them) answer ``i16 status`` first, then the body when
status is 0. Writes answer exactly one ``i16 status`` (seed). ODBALMHIS (0x0F1A) answers ``num_alm``
first, negative meaning a CNC error, and its decoder never raises.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from decimal import Decimal

from edge.focas.errors import (
    EW_LENGTH,
    EW_OK,
    EW_PASSWD,
    AccessDenied,
    CncError,
    LengthError,
    OutOfRange,
    ProtocolError,
    cnc_error,
)
from edge.focas.model import (
    ActiveAlarm,
    AlarmHistoryEntry,
    ModalGCode,
    ParamRecord,
    ParamType,
    PmcType,
    ProgramNumbers,
    StatInfo,
    SysInfo,
    TimerValue,
)


class Command(enum.IntEnum):
    """The append-only command-id table. Never renumber, never reuse an id."""

    # --- the seed's ids -----------------------------------------------------------------------------
    RDCNCSTAT = 0x0001  # cnc_rdcncstat: ODBST, 9 x i16
    RDPARAM = 0x0002  # cnc_rdparam: one parameter number
    RDMACRO = 0x0003  # cnc_rdmacro: one macro variable
    RDDIAG = 0x0004  # cnc_rddiag: one diagnosis number
    WRPARAM = 0x0102  # cnc_wrparam: IODBPSD
    WRMACRO = 0x0103  # cnc_wrmacro: ODBM
    WRPMCRNG = 0x0104  # pmc_wrpmcrng: IODBPMC
    RDALMHISTRY = 0x0F1A  # cnc_rdalmhistry: ODBALMHIS
    # --- focas-edge extensions: the 0x4000 block, far from every id the seed (or lmxopcua) uses --------
    SYSINFO = 0x4001  # cnc_sysinfo: ODBSYS
    RDPMCRNG = 0x4002  # pmc_rdpmcrng: IODBPMC, the 0x0104 packet read back
    GETTIME = 0x4003  # cnc_gettime: CNC local date and time
    RDALMMSG = 0x4004  # cnc_rdalmmsg: active alarms with text
    ALARM = 0x4005  # cnc_alarm: alarm status bitfield
    RDPRGNUM = 0x4006  # cnc_rdprgnum: running and main program numbers
    RDSEQNUM = 0x4007  # cnc_rdseqnum: sequence number
    POSITION = 0x4008  # cnc_absolute/machine/relative/distance: one value per axis
    ACTF = 0x4009  # cnc_actf: actual feed
    ACTS = 0x400A  # cnc_acts: actual spindle speed
    RDAXISNAME = 0x400B  # cnc_rdaxisname: axis names
    RDTIMER = 0x400C  # cnc_rdtimer: minutes + milliseconds
    RDZOFS = 0x400D  # cnc_rdzofs: one work-coordinate offset, every axis (IODBZOFS)
    RDGCODE = 0x400E  # cnc_rdgcode: modal G codes of the active block (ODBGCD)
    RDTOOLNUM = 0x400F  # cnc_modal type 108: the T code in use (ODBMDL aux)


# Ids another implementation of the surface uses with a layout we do not know; never assign them.
RESERVED_IDS: dict[int, str] = {0x0105: "cnc_wrunlockparam (lmxopcua; 4-byte password, layout unpublished)"}

FOCAS_NAMES: dict[Command, str] = {
    Command.RDCNCSTAT: "cnc_rdcncstat",
    Command.RDPARAM: "cnc_rdparam",
    Command.RDMACRO: "cnc_rdmacro",
    Command.RDDIAG: "cnc_rddiag",
    Command.WRPARAM: "cnc_wrparam",
    Command.WRMACRO: "cnc_wrmacro",
    Command.WRPMCRNG: "pmc_wrpmcrng",
    Command.RDALMHISTRY: "cnc_rdalmhistry",
    Command.SYSINFO: "cnc_sysinfo",
    Command.RDPMCRNG: "pmc_rdpmcrng",
    Command.GETTIME: "cnc_gettime",
    Command.RDALMMSG: "cnc_rdalmmsg",
    Command.ALARM: "cnc_alarm",
    Command.RDPRGNUM: "cnc_rdprgnum",
    Command.RDSEQNUM: "cnc_rdseqnum",
    Command.POSITION: "cnc_position",
    Command.ACTF: "cnc_actf",
    Command.ACTS: "cnc_acts",
    Command.RDAXISNAME: "cnc_rdaxisname",
    Command.RDTIMER: "cnc_rdtimer",
    Command.RDZOFS: "cnc_rdzofs",
    Command.RDGCODE: "cnc_rdgcode",
    Command.RDTOOLNUM: "cnc_modal",
}


def command_name(command: int) -> str:
    """The FOCAS name of a command id, or its hex form for an id outside the table."""
    try:
        return FOCAS_NAMES[Command(command)]
    except ValueError:
        return f"packed-0x{command:04X}"


# ---- statuses -------------------------------------------------------------------------------------
# The seed's surface reports EW_PASSWD as 11, while fwlib32.h (and the native protocol) has EW_PASSWD = 17
# and EW_PATH = 11. The surface is single-path, so 11 here always means "password/parameter-write lock";
# we accept 17 too, for bridges that pass the vendor library's code through unchanged.
PACKED_EW_PASSWD = 11
_ACCESS_DENIED_STATUSES = frozenset({PACKED_EW_PASSWD, EW_PASSWD})

_I16 = struct.Struct("<h")


def status_error(status: int, command: int) -> CncError | None:
    """The typed error for a non-zero status of this surface; None for 0 (good)."""
    if status == EW_OK:
        return None
    function = command_name(command)
    if status in _ACCESS_DENIED_STATUSES:
        return AccessDenied(EW_PASSWD, function, message=(
            f"packed status {status}: parameter-write switch off or CNC not in MDI"))
    return cnc_error(status, function)


def encode_status(status: int) -> bytes:
    """A write response (seed: one i16), and the status prefix of every read response."""
    return _I16.pack(status)


def decode_status(payload: bytes, command: int) -> None:
    """Check a write response: exactly one i16 status; raise its typed error when it is not 0."""
    if len(payload) != 2:
        raise ProtocolError(
            f"{command_name(command)}: expected a 2-byte status response, got {len(payload)} bytes"
        )
    _raise_for(_I16.unpack(payload)[0], command)


def _raise_for(status: int, command: int) -> None:
    error = status_error(status, command)
    if error is not None:
        raise error


def _body_after_status(payload: bytes, command: int) -> bytes:
    """A read response: i16 status, then the body; raise the status's error when it is not 0."""
    if len(payload) < 2:
        raise ProtocolError(
            f"{command_name(command)}: expected at least a 2-byte status, got {len(payload)} bytes"
        )
    _raise_for(_I16.unpack_from(payload)[0], command)
    return payload[2:]


def read_response(body: bytes) -> bytes:
    """Server side: a successful read response (status 0, then the body)."""
    return encode_status(EW_OK) + body


def _expect_length(body: bytes, length: int, what: str) -> None:
    if len(body) != length:
        raise ProtocolError(f"{what}: expected {length} bytes, got {len(body)}")


def _unpack(fmt: struct.Struct, body: bytes, what: str) -> tuple[int, ...]:
    _expect_length(body, fmt.size, what)
    return fmt.unpack(body)


# ---- scaled values (ODBM mcr_val/dec_val, REALPRM prm_val/dec_val) -------------------------------------
I32_MIN, I32_MAX = -(2**31), 2**31 - 1


def to_scaled(value: float, what: str = "value") -> tuple[int, int]:
    """(mantissa, decimals) with value == mantissa / 10**decimals, mantissa within int32.

    12.345 -> (12345, 3). A value with more significant digits than int32 holds is rounded to the most
    decimals that fit; one whose integer part does not fit raises OutOfRange.
    """
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise OutOfRange(5, what, message=f"expected a finite number, got {value!r}")
    exact = (Decimal(value) if isinstance(value, int) else Decimal(repr(value))).normalize()
    decimals = max(0, -int(exact.as_tuple().exponent))
    while True:
        mantissa = int(exact.scaleb(decimals).to_integral_value())
        if I32_MIN <= mantissa <= I32_MAX:
            return mantissa, decimals
        if decimals == 0:
            raise OutOfRange(5, what, message=f"{value!r} does not fit a 32-bit scaled integer")
        decimals -= 1


def from_scaled(mantissa: int, decimals: int) -> float:
    return mantissa / 10**decimals


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
    return CncStatus(*_unpack(_ODBST, body, "ODBST"))


def decode_cncstat_response(payload: bytes) -> CncStatus:
    return decode_cncstat(_body_after_status(payload, Command.RDCNCSTAT))


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
    _expect_length(data, width, f"IODBPSD data of type {ptype}")
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
    number, axis = _unpack(_PARAM_READ_REQUEST, payload, "cnc_rdparam request")
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
    return decode_param_record(_body_after_status(payload, command), command_name(command))


# ---- ODBM (0x0003 read, 0x0103 write) ------------------------------------------------------------------
# ODBM: i16 datano | i16 length (always 8) | i32 mcr_val | i16 dec_val. Value = mcr_val / 10**dec_val;
# a read with dec_val < 0 (the CNC answers mcr_val 0, dec_val -1) is a vacant variable.
_ODBM = struct.Struct("<hhih")
ODBM_LENGTH = 8
VACANT = (0, -1)


def encode_macro(number: int, value: float | None) -> bytes:
    """ODBM for `value` (None = vacant): the 0x0103 request and the 0x0003 response body alike."""
    mantissa, decimals = VACANT if value is None else to_scaled(value, f"macro #{number}")
    return _ODBM.pack(number, ODBM_LENGTH, mantissa, decimals)


def decode_macro(body: bytes, what: str = "ODBM") -> tuple[int, float | None]:
    number, length, mantissa, decimals = _unpack(_ODBM, body, what)
    if length != ODBM_LENGTH:
        raise ProtocolError(f"{what}: expected length field {ODBM_LENGTH}, got {length}")
    return number, None if decimals < 0 else from_scaled(mantissa, decimals)


def decode_macro_raw(body: bytes, what: str = "ODBM") -> tuple[int, int, int]:
    """(number, mcr_val, dec_val) as sent, for a server that stores the scaled form."""
    number, length, mantissa, decimals = _unpack(_ODBM, body, what)
    if length != ODBM_LENGTH:
        raise ProtocolError(f"{what}: expected length field {ODBM_LENGTH}, got {length}")
    return number, mantissa, decimals


def encode_macro_read(number: int) -> bytes:
    return _I16.pack(number)


def decode_macro_read(payload: bytes) -> int:
    return int(_unpack(_I16, payload, "cnc_rdmacro request")[0])


def decode_macro_response(payload: bytes) -> tuple[int, float | None]:
    return decode_macro(_body_after_status(payload, Command.RDMACRO), "cnc_rdmacro")


# ---- IODBPMC (0x4002 read, 0x0104 write) ---------------------------------------------------------------
# IODBPMC: i16 type_a | i16 type_d | u16 datano_s | u16 datano_e (inclusive) | data (e - s + 1 bytes).
# type_a uses the seed's letter codes, which differ from the native protocol's (G0 F1 Y2 X3 A4 R5 ...).
PMC_TYPE_A: dict[str, int] = {
    "X": 1, "Y": 2, "F": 3, "G": 4, "R": 5, "T": 6, "C": 7, "D": 8, "K": 10, "A": 11, "E": 12,
}
PMC_AREA_BY_TYPE_A: dict[int, str] = {code: area for area, code in PMC_TYPE_A.items()}
PMC_MAX_WRITE = 32
_IODBPMC_HEAD = struct.Struct("<hhHH")
_PMC_ELEMENTS: dict[PmcType, struct.Struct] = {t: struct.Struct("<" + t.struct_code) for t in PmcType}


@dataclass(frozen=True, slots=True)
class PmcRange:
    """A decoded IODBPMC: area letter, data type, inclusive byte addresses, and the data (may be empty)."""

    area: str
    data_type: int
    start: int
    end: int
    data: bytes = b""

    @property
    def byte_count(self) -> int:
        return self.end - self.start + 1


def pmc_type_a(area: str) -> int:
    try:
        return PMC_TYPE_A[area.upper()]
    except KeyError:
        raise OutOfRange(
            4, "IODBPMC", message=f"PMC area {area!r} has no packed type_a code (have {''.join(PMC_TYPE_A)})"
        ) from None


def encode_pmc_write(area: str, start: int, data: bytes) -> bytes:
    """0x0104 request: byte writes only (type_d 0), at most 32 bytes (the caller chunks)."""
    if not 1 <= len(data) <= PMC_MAX_WRITE:
        raise LengthError(EW_LENGTH, "pmc_wrpmcrng",
                         message=f"expected 1..{PMC_MAX_WRITE} bytes per call, got {len(data)}")
    return _IODBPMC_HEAD.pack(pmc_type_a(area), PmcType.BYTE, start, start + len(data) - 1) + bytes(data)


def encode_pmc_read(area: str, start: int, end: int, data_type: int = PmcType.BYTE) -> bytes:
    """0x4002 request: the IODBPMC header alone."""
    return _IODBPMC_HEAD.pack(pmc_type_a(area), data_type, start, end)


def encode_pmc_range(rng: PmcRange) -> bytes:
    """IODBPMC with its data: the 0x0104 request and the 0x4002 response body."""
    return _IODBPMC_HEAD.pack(pmc_type_a(rng.area), rng.data_type, rng.start, rng.end) + rng.data


class PmcCodeError(ProtocolError):
    """An IODBPMC names a type_a the surface does not define (the server answers EW_ATTRIB)."""


def decode_pmc_range(payload: bytes, with_data: bool, what: str = "IODBPMC") -> PmcRange:
    """Parse IODBPMC; with_data demands exactly (e - s + 1) data bytes, else none at all."""
    if len(payload) < _IODBPMC_HEAD.size:
        raise ProtocolError(f"{what}: expected an 8-byte IODBPMC header, got {len(payload)} bytes")
    type_a, type_d, start, end = _IODBPMC_HEAD.unpack_from(payload)
    data = payload[_IODBPMC_HEAD.size :]
    if end < start:
        raise ProtocolError(f"{what}: datano_e {end} is before datano_s {start}")
    expected = end - start + 1 if with_data else 0
    if len(data) != expected:
        raise ProtocolError(
            f"{what}: datano {start}..{end} needs exactly {expected} data bytes, got {len(data)}"
        )
    area = PMC_AREA_BY_TYPE_A.get(type_a)
    if area is None:
        raise PmcCodeError(f"{what}: unknown type_a {type_a} (expected one of {sorted(PMC_AREA_BY_TYPE_A)})")
    return PmcRange(area, type_d, start, end, data)


def pmc_values(data_type: int, data: bytes) -> list[int | float]:
    """Split PMC data into elements of data_type (little-endian; bytes unsigned)."""
    try:
        element = _PMC_ELEMENTS[PmcType(data_type)]
    except ValueError:
        raise ProtocolError(f"IODBPMC: unknown type_d {data_type}") from None
    if len(data) % element.size:
        raise ProtocolError(
            f"IODBPMC: {len(data)} data bytes are not a whole number of {element.size}-byte elements"
        )
    return [v for (v,) in element.iter_unpack(data)]


def decode_pmc_read_response(payload: bytes) -> PmcRange:
    return decode_pmc_range(_body_after_status(payload, Command.RDPMCRNG), True, "pmc_rdpmcrng")


# ---- ODBALMHIS (0x0F1A) --------------------------------------------------------------------------------
# Request: i16 depth, clamped to 1..250. Response: i16 num_alm (< 0: CNC error), then num_alm entries of
# ten i16 (year, month, day, hour, minute, second, axis_no, alm_type, alm_no, msg_len), msg_len ASCII
# bytes, and zero padding so each entry block is a multiple of 4 bytes long (20 + msg_len + pad).
ALMHIS_MIN_DEPTH = 1
ALMHIS_MAX_DEPTH = 250
_ALMHIS_ENTRY = struct.Struct("<10h")


def clamp_depth(depth: int) -> int:
    return max(ALMHIS_MIN_DEPTH, min(ALMHIS_MAX_DEPTH, depth))


def encode_alarm_history_request(depth: int) -> bytes:
    return _I16.pack(clamp_depth(depth))


def decode_alarm_history_request(payload: bytes) -> int:
    """Server side; a missing or odd request is read as the largest depth (clamping covers the rest)."""
    if len(payload) < 2:
        return ALMHIS_MAX_DEPTH
    return clamp_depth(_I16.unpack_from(payload)[0])


def almhis_padding(msg_len: int) -> int:
    """Pad bytes after an entry's message so the block (20 + msg_len + pad) ends on a 4-byte boundary."""
    return -msg_len % 4


@dataclass(frozen=True, slots=True)
class AlarmHistoryRow:
    """One ODBALMHIS entry as raw fields: a bridge passes the CNC's date fields through unchecked (the
    decoder skips an impossible date), which a datetime could not carry."""

    year: int
    month: int
    day: int
    hour: int
    minute: int
    second: int
    axis_no: int
    alm_type: int
    alm_no: int
    message: bytes


def encode_alarm_history(entries: Sequence[AlarmHistoryEntry]) -> bytes:
    """ODBALMHIS for `entries` (newest first). Times are converted to UTC; sub-second parts are dropped."""
    rows = []
    for entry in entries:
        when = entry.occurred.astimezone(UTC) if entry.occurred.tzinfo else entry.occurred
        rows.append(AlarmHistoryRow(when.year, when.month, when.day, when.hour, when.minute, when.second,
                                    entry.axis_no, entry.alm_type, entry.alm_no,
                                    entry.message.encode("ascii", errors="replace")))
    return encode_alarm_history_rows(rows)


def encode_alarm_history_rows(rows: Sequence[AlarmHistoryRow]) -> bytes:
    """ODBALMHIS from raw rows (newest first), each block padded to a multiple of 4 from its start."""
    blocks = [_I16.pack(len(rows))]
    for row in rows:
        blocks.append(_ALMHIS_ENTRY.pack(row.year, row.month, row.day, row.hour, row.minute, row.second,
                                         row.axis_no, row.alm_type, row.alm_no, len(row.message)))
        blocks.append(row.message + b"\x00" * almhis_padding(len(row.message)))
    return b"".join(blocks)


def encode_alarm_history_error(status: int) -> bytes:
    """A CNC error on 0x0F1A: num_alm = -status (any negative means error; the client sees none)."""
    return _I16.pack(-abs(status) or -1)


def decode_alarm_history(payload: bytes) -> list[AlarmHistoryEntry]:
    """The seed's error rules, and never an exception on a bad payload.

    num_alm < 0 -> empty list; a malformed timestamp skips that entry only; an entry whose header or
    message runs past the payload (or has a negative msg_len) ends the list there. A final entry whose
    padding is missing is kept.
    """
    if len(payload) < 2:
        return []
    (num_alm,) = _I16.unpack_from(payload)
    entries: list[AlarmHistoryEntry] = []
    offset = 2
    for _ in range(max(0, num_alm)):
        if offset + _ALMHIS_ENTRY.size > len(payload):
            break
        year, month, day, hour, minute, second, axis_no, alm_type, alm_no, msg_len = (
            _ALMHIS_ENTRY.unpack_from(payload, offset)
        )
        text_at = offset + _ALMHIS_ENTRY.size
        if msg_len < 0 or text_at + msg_len > len(payload):
            break
        message = payload[text_at : text_at + msg_len].decode("ascii", errors="replace")
        offset = text_at + msg_len + almhis_padding(msg_len)
        try:
            occurred = datetime(year, month, day, hour, minute, second, tzinfo=UTC)
        except ValueError:
            continue
        entries.append(AlarmHistoryEntry(occurred, axis_no, alm_type, alm_no, message))
    return entries


# ---- ODBSYS (0x4001) -----------------------------------------------------------------------------------
_ODBSYS = struct.Struct("<hh2s2s4s4s2s")


def _ascii_field(text: str, width: int) -> bytes:
    return text.encode("ascii", errors="replace")[:width].ljust(width, b" ")


def encode_sysinfo(info: SysInfo) -> bytes:
    return _ODBSYS.pack(info.addinfo, info.max_axis, _ascii_field(info.cnc_type, 2),
                        _ascii_field(info.mt_type, 2), _ascii_field(info.series, 4),
                        _ascii_field(info.version, 4), _ascii_field(info.axes, 2))


def decode_sysinfo_response(payload: bytes) -> SysInfo:
    addinfo, max_axis, *texts = _unpack(_ODBSYS, _body_after_status(payload, Command.SYSINFO), "ODBSYS")
    cnc_type, mt_type, series, version, axes = (bytes(t).decode("ascii", errors="replace") for t in texts)
    return SysInfo(addinfo, max_axis, cnc_type, mt_type, series, version, axes)


# ---- clock (0x4003) ------------------------------------------------------------------------------------
_CLOCK = struct.Struct("<6h")


def encode_clock(when: datetime) -> bytes:
    """The CNC's local wall-clock time as six i16: year, month, day, hour, minute, second."""
    return _CLOCK.pack(when.year, when.month, when.day, when.hour, when.minute, when.second)


def decode_clock_response(payload: bytes) -> datetime:
    fields = _unpack(_CLOCK, _body_after_status(payload, Command.GETTIME), "cnc_gettime")
    year, month, day, hour, minute, second = fields
    try:
        return datetime(year, month, day, hour, minute, second)
    except ValueError as exc:
        raise ProtocolError(f"cnc_gettime: impossible date/time {fields}: {exc}") from None


# ---- active alarms (0x4004) ----------------------------------------------------------------------------
# Request: i16 max_count. Response body: i16 count, then per alarm i32 alm_no | i16 type | i16 axis |
# i16 msg_len | msg | pad to a 4-byte block (10 + msg_len + pad, padded like ODBALMHIS).
_ALMMSG_ENTRY = struct.Struct("<ihhh")


def encode_alarm_messages(alarms: Sequence[ActiveAlarm]) -> bytes:
    blocks = [_I16.pack(len(alarms))]
    for alarm in alarms:
        message = alarm.message.encode("ascii", errors="replace")
        pad = -(_ALMMSG_ENTRY.size + len(message)) % 4
        blocks.append(_ALMMSG_ENTRY.pack(alarm.number, alarm.type, alarm.axis, len(message)))
        blocks.append(message + b"\x00" * pad)
    return b"".join(blocks)


def decode_alarm_messages_response(payload: bytes) -> list[ActiveAlarm]:
    body = _body_after_status(payload, Command.RDALMMSG)
    if len(body) < 2:
        raise ProtocolError(f"cnc_rdalmmsg: expected an i16 count, got {len(body)} bytes")
    (count,) = _I16.unpack_from(body)
    alarms: list[ActiveAlarm] = []
    offset = 2
    for index in range(count):
        if offset + _ALMMSG_ENTRY.size > len(body):
            raise ProtocolError(
                f"cnc_rdalmmsg: alarm {index} of {count} starts past the {len(body)}-byte body"
            )
        number, atype, axis, msg_len = _ALMMSG_ENTRY.unpack_from(body, offset)
        text_at = offset + _ALMMSG_ENTRY.size
        if msg_len < 0 or text_at + msg_len > len(body):
            raise ProtocolError(f"cnc_rdalmmsg: alarm {index} msg_len {msg_len} runs past the body")
        message = body[text_at : text_at + msg_len].decode("ascii", errors="replace")
        offset = text_at + msg_len + (-(_ALMMSG_ENTRY.size + msg_len) % 4)
        alarms.append(ActiveAlarm(number, atype, axis, message))
    return alarms


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
    return int(_unpack(_I32, _body_after_status(payload, command), command_name(command))[0])


def encode_program_numbers(numbers: ProgramNumbers) -> bytes:
    return _TWO_I32.pack(numbers.running, numbers.main)


def decode_program_numbers_response(payload: bytes) -> ProgramNumbers:
    running, main = _unpack(_TWO_I32, _body_after_status(payload, Command.RDPRGNUM), "cnc_rdprgnum")
    return ProgramNumbers(running, main)


def encode_timer(timer: TimerValue) -> bytes:
    return _TWO_I32.pack(timer.minutes, timer.msec)


def decode_timer_response(payload: bytes) -> TimerValue:
    minutes, msec = _unpack(_TWO_I32, _body_after_status(payload, Command.RDTIMER), "cnc_rdtimer")
    return TimerValue(minutes, msec)


def encode_i16(value: int) -> bytes:
    """A one-i16 request (depth, max_count, position kind, timer kind, macro number)."""
    return _I16.pack(value)


def decode_i16_request(payload: bytes, what: str) -> int:
    return int(_unpack(_I16, payload, what)[0])


def encode_float(value: float | None) -> bytes:
    """f64 LE; NaN stands for "no value"."""
    return _F64.pack(math.nan if value is None else value)


def _optional_float(value: float) -> float | None:
    return None if math.isnan(value) else value


def decode_float_response(payload: bytes, command: int) -> float | None:
    return _optional_float(_unpack(_F64, _body_after_status(payload, command), command_name(command))[0])


def encode_floats(values: Sequence[float | None]) -> bytes:
    """i16 count, then count f64 (NaN = no value): positions per axis."""
    return _I16.pack(len(values)) + b"".join(encode_float(v) for v in values)


def decode_floats_response(payload: bytes, command: int) -> list[float | None]:
    body = _body_after_status(payload, command)
    if len(body) < 2:
        raise ProtocolError(f"{command_name(command)}: expected an i16 count, got {len(body)} bytes")
    (count,) = _I16.unpack_from(body)
    _expect_length(body, 2 + _F64.size * max(count, 0), f"{command_name(command)} with {count} values")
    return [_optional_float(v) for (v,) in _F64.iter_unpack(body[2:])]


def encode_axis_names(names: Sequence[str]) -> bytes:
    """i16 count, then count 4-byte ASCII names, NUL-padded."""
    return _I16.pack(len(names)) + b"".join(
        n.encode("ascii", errors="replace")[:AXIS_NAME_WIDTH].ljust(AXIS_NAME_WIDTH, b"\x00") for n in names
    )


def decode_axis_names_response(payload: bytes) -> list[str]:
    body = _body_after_status(payload, Command.RDAXISNAME)
    if len(body) < 2:
        raise ProtocolError(f"cnc_rdaxisname: expected an i16 count, got {len(body)} bytes")
    (count,) = _I16.unpack_from(body)
    _expect_length(body, 2 + AXIS_NAME_WIDTH * max(count, 0), f"cnc_rdaxisname with {count} names")
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
    return _I16.pack(len(codes)) + b"".join(
        _GCODE_HEAD.pack(c.group) + c.code.encode("ascii", errors="replace")[:G_CODE_WIDTH].ljust(G_CODE_WIDTH, b"\x00")
        for c in codes)


def decode_modal_g_codes_response(payload: bytes) -> list[ModalGCode]:
    body = _body_after_status(payload, Command.RDGCODE)
    if len(body) < 2:
        raise ProtocolError(f"cnc_rdgcode: expected an i16 count, got {len(body)} bytes")
    (count,) = _I16.unpack_from(body)
    entry = _GCODE_HEAD.size + G_CODE_WIDTH
    _expect_length(body, 2 + entry * max(count, 0), f"cnc_rdgcode with {count} codes")
    codes = []
    for at in range(2, len(body), entry):
        (group,) = _GCODE_HEAD.unpack_from(body, at)
        raw = body[at + _GCODE_HEAD.size : at + entry]
        codes.append(ModalGCode(group, raw.rstrip(b"\x00").decode("ascii", errors="replace")))
    return codes


# ---- T code in use (0x400F): empty request, answer i32 (encode_int32) ------------------------------------
def decode_tool_number_response(payload: bytes) -> int:
    return decode_int32_response(payload, Command.RDTOOLNUM)
