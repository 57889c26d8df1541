"""The FOCAS function table: one declarative entry per function, shared by client and simulated CNC.

What an entry is (Function, Context, Evidence) lives in function_entry.py; this module is the table and its
private payload codecs, each a few lines and named by exactly one entry further down, so that an entry
reads beside its codec, and both beside docs/protocol.md. Shared value encodings live in values.py and the
frame in frame.py. Split the table by area (as packed/ is) when it grows by another block of functions.

Like pymodbus' PDU table, the same entry builds and parses both directions, so the simulator can never
disagree with the client about a layout. An entry knows its class (1 CNC, 2 PMC), command, the names of
its five i32 args, how its response payload decodes to a typed value (edge.focas.model types) and back,
and - for writes - how the value travels in the request's extra bytes.

Client side::

    req = READ_MACROS.request(500, 505)                    # or a typed builder below
    frame = encode_request([req, ...])                     # edge.focas.frame
    ...
    value = READ_MACROS.decode_response(sub, req, ctx)     # raises the item's CncError if rc != 0

Server side (the simulated CNC), for every subpacket of a parsed 0x2101 request::

    req: RequestSubpacket                                  # from frame.decode_request_body(frame.body)
    fn = BY_COMMAND.get((req.cls, req.command))            # None -> answer fn-less EW_FUNC:
                                                           #   error_response(req, EW_FUNC)
    args = fn.named_args(req)                              # e.g. {"first": 500, "last": 505}
    written = fn.decode_extra(req, ctx) if fn.is_write else None   # value a write carries
    value = <look up / apply in the machine model>         # typed, as the table's `returns` says
    sub = fn.response(req, value, ctx)                     # ResponseSubpacket with encoded payload
    # or, on failure: error_response(req, EW_NUMBER, detail)
    encode_response([sub, ...], version=profile_version)   # same order as the request

`ctx` is a Context (max_axis and the parameter/diagnosis slot form of the profile); both ends must use
the same one, which the client derives from sysinfo. Value types per function are listed in `returns`.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from datetime import date, datetime, time
from typing import Any

from edge.focas.errors import ProtocolError
from edge.focas.frame import CLASS_CNC, CLASS_PMC, RequestSubpacket
from edge.focas.function_entry import (
    Context,
    Evidence,
    Function,
    PayloadDecoder,
    PayloadEncoder,
)
from edge.focas.model import (
    PMC_AREAS,
    ActiveAlarm,
    ExecProgram,
    OperatorMessage,
    ProgramDirEntry,
    ProgramNumbers,
    StatInfo,
    SysInfo,
    TimerValue,
)
from edge.focas.values import (
    ALL_AXES,
    SCALED_SIZE,
    SlotForm,
    c_string,
    decode_pmc,
    decode_records,
    decode_scaled,
    decode_scaled_list,
    encode_pmc,
    encode_records,
    encode_scaled,
    encode_scaled_list,
    pad_c_string,
    pmc_type,
)

# ---- payload codecs -----------------------------------------------------------------------------------


def _need(payload: bytes, size: int, what: str, exact: bool = True) -> None:
    if len(payload) < size or (exact and len(payload) != size):
        rule = "" if exact else "at least "
        raise ProtocolError(f"{what}: expected {rule}{size} payload bytes, got {len(payload)}")


_SYSINFO = struct.Struct(">Hh2s2s4s4s2s")


def _sysinfo_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> SysInfo:
    _need(payload, _SYSINFO.size, "sysinfo", exact=False)
    addinfo, max_axis, cnc, mt, series, version, axes = _SYSINFO.unpack_from(payload)
    return SysInfo(addinfo, max_axis, *(s.decode("latin-1") for s in (cnc, mt, series, version, axes)))


def _sysinfo_encode(value: SysInfo, req: RequestSubpacket, ctx: Context) -> bytes:
    def text(s: str, n: int) -> bytes:
        return s.encode("latin-1")[:n].ljust(n, b" ")

    return _SYSINFO.pack(value.addinfo, value.max_axis, text(value.cnc_type, 2), text(value.mt_type, 2),
                         text(value.series, 4), text(value.version, 4), text(value.axes, 2))


_STATINFO = struct.Struct(">7h")


def _statinfo_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> StatInfo:
    _need(payload, _STATINFO.size, "statinfo")
    return StatInfo(*_STATINFO.unpack(payload))


def _statinfo_encode(value: StatInfo, req: RequestSubpacket, ctx: Context) -> bytes:
    return _STATINFO.pack(value.aut, value.run, value.motion, value.mstb, value.emergency, value.alarm,
                          value.edit)


def _alarm_status_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> int:
    if len(payload) == 2:
        return int(struct.unpack(">H", payload)[0])
    _need(payload, 4, "alarm status")
    return int(struct.unpack(">I", payload)[0])


def _alarm_status_encode(value: int, req: RequestSubpacket, ctx: Context) -> bytes:
    return struct.pack(">I", value)


_ALARM_HEAD = struct.Struct(">iiii")


def _alarm_text_len(req: RequestSubpacket) -> int:
    return max(0, req.args[3])


def _alarms_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[ActiveAlarm]:
    stride = _ALARM_HEAD.size + _alarm_text_len(req)
    if len(payload) % stride:
        raise ProtocolError(f"alarm messages: expected records of {stride} bytes (16 + text length "
                            f"{_alarm_text_len(req)}), got a {len(payload)}-byte payload")
    alarms = []
    for start in range(0, len(payload), stride):
        number, atype, axis, msg_len = _ALARM_HEAD.unpack_from(payload, start)
        text = payload[start + 16 : start + stride]
        message = c_string(text[: max(0, min(msg_len, len(text)))]).rstrip()
        alarms.append(ActiveAlarm(number, atype, axis, message))
    return alarms


def _alarms_encode(value: Sequence[ActiveAlarm], req: RequestSubpacket, ctx: Context) -> bytes:
    text_len = _alarm_text_len(req)
    out = bytearray()
    for alarm in list(value)[: max(0, req.args[1])]:
        text = alarm.message.encode("latin-1")[:text_len]
        out += _ALARM_HEAD.pack(alarm.number, alarm.type, alarm.axis, len(text))
        out += text.ljust(text_len, b"\x00")
    return bytes(out)


def _i32_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> int:
    _need(payload, 4, "i32 value")
    return int(struct.unpack(">i", payload)[0])


def _i32_encode(value: int, req: RequestSubpacket, ctx: Context) -> bytes:
    return struct.pack(">i", value)


def _prgnum_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> ProgramNumbers:
    _need(payload, 8, "program number")
    running, main = struct.unpack(">ii", payload)
    return ProgramNumbers(running, main)


def _prgnum_encode(value: ProgramNumbers, req: RequestSubpacket, ctx: Context) -> bytes:
    return struct.pack(">ii", value.running, value.main)


EXEC_NAME_SIZE = 36


def _exec_name_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> ExecProgram:
    _need(payload, 4, "executing program name", exact=False)
    return ExecProgram(int(struct.unpack_from(">i", payload)[0]), c_string(payload[4:]))


def _exec_name_encode(value: ExecProgram, req: RequestSubpacket, ctx: Context) -> bytes:
    return struct.pack(">i", value.number) + pad_c_string(value.name, EXEC_NAME_SIZE)


def _path_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> str:
    return c_string(payload)


def _path_encode(value: str, req: RequestSubpacket, ctx: Context) -> bytes:
    return value.encode("latin-1") + b"\x00"


_PROGDIR = struct.Struct(">II64s")


def _progdir_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[ProgramDirEntry]:
    if len(payload) % _PROGDIR.size:
        raise ProtocolError(f"program directory: expected 72-byte entries, got a {len(payload)}-byte payload")
    entries = []
    for start in range(0, len(payload), _PROGDIR.size):
        number, size, comment = _PROGDIR.unpack_from(payload, start)
        if number == 0:  # an empty entry ends the list
            break
        entries.append(ProgramDirEntry(number, size, c_string(comment)))
    return entries


def _progdir_encode(value: Sequence[ProgramDirEntry], req: RequestSubpacket, ctx: Context) -> bytes:
    return b"".join(_PROGDIR.pack(e.number, e.size, pad_c_string(e.comment, 64)) for e in value)


def _scaled_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> float | None:
    _need(payload, SCALED_SIZE, "scaled value")
    return decode_scaled(payload)


def _scaled_encode(value: float | None, req: RequestSubpacket, ctx: Context) -> bytes:
    return encode_scaled(value)


def _scaled_list_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[float | None]:
    return decode_scaled_list(payload)


def _scaled_list_encode(value: Sequence[float | None], req: RequestSubpacket, ctx: Context) -> bytes:
    return encode_scaled_list(value)


def _counted_scaled_list(what: str, prefix: str = "") -> PayloadDecoder:
    """A decoder of one 8-B scaled value per number args[0]..args[1], the count checked."""

    def decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[float | None]:
        expected = req.args[1] - req.args[0] + 1
        values = decode_scaled_list(payload)
        if len(values) != expected:
            raise ProtocolError(f"{what} {prefix}{req.args[0]}..{prefix}{req.args[1]}: expected {expected} "
                                f"values, got {len(values)}")
        return values

    return decode


_macros_decode = _counted_scaled_list("macro read", "#")
_tool_offsets_decode = _counted_scaled_list("tool offsets")


NAME_SLOT = 4


def _names_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[str]:
    if len(payload) % NAME_SLOT:
        raise ProtocolError(f"names: expected 4-byte entries, got a {len(payload)}-byte payload")
    names = [c_string(payload[i : i + NAME_SLOT]).strip() for i in range(0, len(payload), NAME_SLOT)]
    while names and not names[-1]:
        names.pop()
    return names


def _names_encode(value: Sequence[str], req: RequestSubpacket, ctx: Context) -> bytes:
    return b"".join(pad_c_string(name, NAME_SLOT) for name in value)


def _count_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> int:
    if len(payload) == 4:
        return int(struct.unpack(">i", payload)[0])
    _need(payload, 2, "axis/spindle count")
    return int(struct.unpack(">h", payload)[0])


def _count_encode(value: int, req: RequestSubpacket, ctx: Context) -> bytes:
    return struct.pack(">h", value)


def _records_codecs(form: SlotForm, whole_slots: bool) -> tuple[PayloadDecoder, PayloadEncoder]:
    def decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> Any:
        return decode_records(payload, ctx.max_axis, form, whole_slots=whole_slots)

    def encode(value: Any, req: RequestSubpacket, ctx: Context) -> bytes:
        return encode_records(value, ctx.max_axis, form, whole_slots=whole_slots)

    return decode, encode


_REC4_DECODE, _REC4_ENCODE = _records_codecs(SlotForm.FOUR_BYTE, whole_slots=False)
_REC8_DECODE, _REC8_ENCODE = _records_codecs(SlotForm.SCALED, whole_slots=False)
# Diagnosis records are sized by their slot, never by their type code (see model.DIAG_TYPE_CODES).
_DIAG4_DECODE, _DIAG4_ENCODE = _records_codecs(SlotForm.FOUR_BYTE, whole_slots=True)
_DIAG8_DECODE, _DIAG8_ENCODE = _records_codecs(SlotForm.SCALED, whole_slots=True)


def _pmc_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[int | float]:
    start, end, _adr, dtype, _ = req.args
    expected = end - start + 1
    if len(payload) != expected:
        raise ProtocolError(f"PMC read {start}..{end}: expected {expected} bytes, got {len(payload)}")
    return decode_pmc(payload, pmc_type(dtype))


def _pmc_encode(value: Sequence[int | float], req: RequestSubpacket, ctx: Context) -> bytes:
    return encode_pmc(value, pmc_type(req.args[3]))


CLOCK_PAYLOAD = 12
_CLOCK = struct.Struct(">6h")
CLOCK_DATE = 0
CLOCK_TIME = 1


def _clock_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> date | time:
    """arg1 0 -> date from bytes 0..5; arg1 1 -> time from bytes 6..11 (the other half is unspecified)."""
    _need(payload, CLOCK_PAYLOAD, "clock")
    year, month, day, hour, minute, second = _CLOCK.unpack(payload)
    try:
        if req.args[0] == CLOCK_DATE:
            return date(year, month, day)
        if req.args[0] == CLOCK_TIME:
            return time(hour, minute, second)
    except ValueError as exc:
        raise ProtocolError(f"clock: payload {payload.hex()} is not a valid date/time: {exc}") from None
    raise ProtocolError(f"clock: expected arg1 0 (date) or 1 (time), the request had {req.args[0]}")


def _clock_encode(value: datetime | date | time, req: RequestSubpacket, ctx: Context) -> bytes:
    """A datetime fills both halves; a date or a time fills its half and leaves the other zero."""
    d: tuple[int, int, int] = (0, 0, 0)
    t: tuple[int, int, int] = (0, 0, 0)
    if isinstance(value, datetime):
        d, t = (value.year, value.month, value.day), (value.hour, value.minute, value.second)
    elif isinstance(value, date):
        d = (value.year, value.month, value.day)
    else:
        t = (value.hour, value.minute, value.second)
    return _CLOCK.pack(*d, *t)


def _settime_decode_extra(req: RequestSubpacket, ctx: Context) -> time:
    _need(req.extra, CLOCK_PAYLOAD, "set time extra")
    req_for_time = RequestSubpacket(req.cls, req.command, (CLOCK_TIME, 0, 0, 0, 0), b"", req.path)
    result = _clock_decode(req.extra, req_for_time, ctx)
    assert isinstance(result, time)
    return result


_TIMER = struct.Struct(">ii")
_TIMER_LE = struct.Struct("<ii")
MSEC_PER_MINUTE = 60_000
# 2**24 minutes is 31.9 years of power-on: beyond any real timer. The bound matters when msec is 0: a
# little-endian minute count read big-endian lands at or above 2**24 unless its low byte is 0
# (1 value in 256 stays ambiguous and is read big-endian).
MAX_TIMER_MINUTES = 1 << 24


def _timer_plausible(minutes: int, msec: int) -> bool:
    return 0 <= minutes < MAX_TIMER_MINUTES and 0 <= msec < MSEC_PER_MINUTE


def _timer_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> TimerValue:
    """Big-endian as everywhere else; a 31i-B sends it little-endian, recognised when BE is implausible."""
    _need(payload, _TIMER.size, "timer")
    minutes, msec = _TIMER.unpack(payload)
    if _timer_plausible(minutes, msec):
        return TimerValue(minutes, msec)
    minutes, msec = _TIMER_LE.unpack(payload)
    if _timer_plausible(minutes, msec):
        return TimerValue(minutes, msec)
    raise ProtocolError(f"timer: expected minutes >= 0 and msec 0..59999 in either byte order, got "
                        f"{payload.hex()}")


def _timer_encode(value: TimerValue, req: RequestSubpacket, ctx: Context) -> bytes:
    return _TIMER.pack(value.minutes, value.msec)


def _macro_scaled_extra(req: RequestSubpacket, ctx: Context) -> list[float | None]:
    count = req.args[1] - req.args[0] + 1
    values = decode_scaled_list(req.extra)
    if len(values) != count:
        raise ProtocolError(f"macro write #{req.args[0]}..#{req.args[1]}: expected {count} values, "
                            f"got {len(values)}")
    return values


def _macro_double_extra(req: RequestSubpacket, ctx: Context) -> float:
    _need(req.extra, 8, "macro write (double) extra")
    return float(struct.unpack(">d", req.extra)[0])


def _pmc_write_extra(req: RequestSubpacket, ctx: Context) -> bytes:
    start, end = req.args[0], req.args[1]
    if len(req.extra) != end - start + 1:
        raise ProtocolError(f"PMC write {start}..{end}: expected {end - start + 1} data bytes, "
                            f"got {len(req.extra)}")
    return bytes(req.extra)


_OPMSG_HEAD = struct.Struct(">iii")


def _opmsg_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> list[OperatorMessage]:
    """The first message, as HslCommunication reads it: i32 number, i32 type, i32 text length, text.
    How further messages follow is not public, so bytes after the first message's text are not read."""
    if not payload:
        return []
    _need(payload, _OPMSG_HEAD.size, "operator message", exact=False)
    number, mtype, length = _OPMSG_HEAD.unpack_from(payload)
    text = payload[_OPMSG_HEAD.size : _OPMSG_HEAD.size + max(0, length)]
    return [OperatorMessage(number, mtype, c_string(text).rstrip())]


def _opmsg_encode(value: Sequence[OperatorMessage], req: RequestSubpacket, ctx: Context) -> bytes:
    if not value:
        return b""
    first = value[0]
    text = first.text.encode("latin-1")
    return _OPMSG_HEAD.pack(first.number, first.type, len(text)) + text


# ---- the table ----------------------------------------------------------------------------------------

SYSINFO = Function("sysinfo", CLASS_CNC, 0x18, Evidence.DOC, (), "SysInfo",
                   "18 B: u16 addinfo, i16 max_axis, char cnc_type[2], mt_type[2], series[4], version[4], "
                   "axes[2]", _sysinfo_decode, _sysinfo_encode)
STATINFO = Function("statinfo", CLASS_CNC, 0x19, Evidence.DOC, (), "StatInfo",
                    "14 B: 7 x i16 aut, run, motion, mstb, emergency, alarm, edit",
                    _statinfo_decode, _statinfo_encode)
ALARM_STATUS = Function("alarm_status", CLASS_CNC, 0x1A, Evidence.CAPTURE, (), "int",
                        "u32 alarm bitfield (0 = none)", _alarm_status_decode, _alarm_status_encode)
ALARM_MESSAGES = Function("alarm_messages", CLASS_CNC, 0x23, Evidence.CODE,
                          ("type", "count", "with_text", "text_len"), "list[ActiveAlarm]",
                          "records of 16 + text_len B: i32 alm_no, i32 type, i32 axis, i32 msg_len, "
                          "char text[text_len]", _alarms_decode, _alarms_encode)
PROGRAM_NUMBER = Function("program_number", CLASS_CNC, 0x1C, Evidence.CAPTURE, (), "ProgramNumbers",
                          "i32 running, i32 main", _prgnum_decode, _prgnum_encode)
SEQUENCE_NUMBER = Function("sequence_number", CLASS_CNC, 0x1D, Evidence.CAPTURE, (), "int", "i32",
                           _i32_decode, _i32_encode)
EXEC_PROGRAM_NAME = Function("exec_program_name", CLASS_CNC, 0xCF, Evidence.CODE, (), "ExecProgram",
                             "i32 o_num, char name[36]", _exec_name_decode, _exec_name_encode)
MAIN_PROGRAM_PATH = Function("main_program_path", CLASS_CNC, 0xB9, Evidence.CODE, (), "str",
                             "NUL-terminated path", _path_decode, _path_encode)
PROGRAM_DIRECTORY = Function("program_directory", CLASS_CNC, 0x06, Evidence.CODE,
                             ("start", "count", "type"), "list[ProgramDirEntry]",
                             "72-B entries: u32 number, u32 size, char comment[64]; number 0 ends the list",
                             _progdir_decode, _progdir_encode)
ACTUAL_FEED = Function("actual_feed", CLASS_CNC, 0x24, Evidence.CAPTURE, (), "float | None",
                       "8-B scaled", _scaled_decode, _scaled_encode)
ACTUAL_SPINDLE_SPEED = Function("actual_spindle_speed", CLASS_CNC, 0x25, Evidence.CAPTURE, (), "float | None",
                                "8-B scaled", _scaled_decode, _scaled_encode)
SPINDLE_LOAD = Function("spindle_load", CLASS_CNC, 0x40, Evidence.CODE, ("kind", "spindle"),
                        "list[float | None]", "n x 8-B scaled (one per spindle)",
                        _scaled_list_decode, _scaled_list_encode)
POSITIONS = Function("positions", CLASS_CNC, 0x26, Evidence.CAPTURE, ("type", "axis"), "list[float | None]",
                     "n x 8-B scaled (max_axis slots); type 4 absolute, 1 machine, 6 relative, 7 distance",
                     _scaled_list_decode, _scaled_list_encode)
AXIS_NAMES = Function("axis_names", CLASS_CNC, 0x89, Evidence.CAPTURE, (), "list[str]",
                      "4 B per axis: name char + 3 bytes (NUL); trailing empty entries dropped",
                      _names_decode, _names_encode)
SPINDLE_NAMES = Function("spindle_names", CLASS_CNC, 0x8A, Evidence.CODE, (), "list[str]", "as axis_names",
                         _names_decode, _names_encode)
SERVO_METER = Function("servo_meter", CLASS_CNC, 0x56, Evidence.CAPTURE, ("type",), "list[float | None]",
                       "max_axis x 8-B scaled", _scaled_list_decode, _scaled_list_encode)
CONTROLLED_AXES = Function("controlled_axes", CLASS_CNC, 0xA4, Evidence.CAPTURE, ("what",), "int",
                           "i16 count (what 2 = controlled axes)", _count_decode, _count_encode)
READ_PARAMS_4 = Function("read_params", CLASS_CNC, 0x0E, Evidence.CAPTURE, ("first", "last", "axis"),
                         "list[ParamRecord]", "records: i32 number, i16 axis, i16 type, max_axis x 4-B slots",
                         _REC4_DECODE, _REC4_ENCODE)
READ_PARAMS_8 = Function("read_params", CLASS_CNC, 0x8D, Evidence.CAPTURE, ("first", "last", "axis"),
                         "list[ParamRecord]",
                         "records: i32 number, i16 axis, i16 type, max_axis x 8-B scaled",
                         _REC8_DECODE, _REC8_ENCODE)
READ_DIAG_4 = Function("read_diag", CLASS_CNC, 0x30, Evidence.CAPTURE, ("first", "last", "axis"),
                       "list[ParamRecord]", "records: i32 number, i16 axis, i16 type (diagnosis codes: "
                       "2 = 2-word), max_axis x 4-B slots, each an i32", _DIAG4_DECODE, _DIAG4_ENCODE)
READ_DIAG_8 = Function("read_diag", CLASS_CNC, 0x93, Evidence.CAPTURE, ("first", "last", "axis"),
                       "list[ParamRecord]", "records: i32 number, i16 axis, i16 type (diagnosis codes: "
                       "0 = byte), max_axis x 8-B scaled", _DIAG8_DECODE, _DIAG8_ENCODE)
READ_MACROS = Function("read_macros", CLASS_CNC, 0x15, Evidence.DOC, ("first", "last"), "list[float | None]",
                       "(last - first + 1) x 8-B scaled", _macros_decode, _scaled_list_encode)
WRITE_MACROS = Function("write_macros", CLASS_CNC, 0x16, Evidence.CODE, ("first", "last"),
                        "list[float | None]",
                        "request extra: (last - first + 1) x 8-B scaled; response: no payload",
                        decode_extra=_macro_scaled_extra)
WRITE_MACRO_DOUBLE = Function("write_macro_double", CLASS_CNC, 0xA8, Evidence.DOC, ("number",), "float",
                              "request extra: f64 BE (arg5 = 8); response payload unknown, ignored",
                              decode_extra=_macro_double_extra)
READ_PMC = Function("read_pmc", CLASS_PMC, 0x8001, Evidence.CAPTURE,
                    ("start", "end", "adr_type", "data_type"), "list[int | float]",
                    "(end - start + 1) bytes, elements BE of the data_type width", _pmc_decode, _pmc_encode)
WRITE_PMC = Function("write_pmc", CLASS_PMC, 0x8002, Evidence.CODE, ("start", "end", "adr_type", "data_type"),
                     "bytes", "request extra: (end - start + 1) raw bytes; response: no payload",
                     decode_extra=_pmc_write_extra)
READ_CLOCK = Function("read_clock", CLASS_CNC, 0x45, Evidence.DOC, ("part",), "date (part 0) | time (part 1)",
                      "12 B: i16 year, month, day (part 0) | i16 hour, minute, second (part 1)",
                      _clock_decode, _clock_encode)
SET_TIME = Function("set_time", CLASS_CNC, 0x46, Evidence.CODE, ("part",), "time",
                    "request (1,0,0,0,12) + extra 6 x 00, i16 hour, minute, second; response: no payload",
                    decode_extra=_settime_decode_extra)
READ_TIMER = Function("read_timer", CLASS_CNC, 0x120, Evidence.CODE, ("type",), "TimerValue",
                      "i32 minute, i32 msec (little-endian on a 31i-B)", _timer_decode, _timer_encode)

TOOL_OFFSETS = Function("tool_offsets", CLASS_CNC, 0x08, Evidence.CODE, ("first", "last", "type"),
                        "list[float | None]", "(last - first + 1) x 8-B scaled; type 0 length geometry, "
                        "1 length wear, 2 radius geometry, 3 radius wear", _tool_offsets_decode,
                        _scaled_list_encode)
OPERATOR_MESSAGES = Function("operator_messages", CLASS_CNC, 0x34, Evidence.CODE, (), "list[OperatorMessage]",
                             "i32 number, i32 type, i32 text_len, char text[text_len] (the first message; "
                             "the form of further ones is not public)", _opmsg_decode, _opmsg_encode)

FUNCTIONS: tuple[Function, ...] = (
    SYSINFO, STATINFO, ALARM_STATUS, ALARM_MESSAGES, PROGRAM_NUMBER, SEQUENCE_NUMBER, EXEC_PROGRAM_NAME,
    MAIN_PROGRAM_PATH, PROGRAM_DIRECTORY, ACTUAL_FEED, ACTUAL_SPINDLE_SPEED, SPINDLE_LOAD, POSITIONS,
    AXIS_NAMES, SPINDLE_NAMES, SERVO_METER, CONTROLLED_AXES, READ_PARAMS_4, READ_PARAMS_8, READ_DIAG_4,
    READ_DIAG_8, READ_MACROS, WRITE_MACROS, WRITE_MACRO_DOUBLE, READ_PMC, WRITE_PMC, READ_CLOCK, SET_TIME,
    READ_TIMER, TOOL_OFFSETS, OPERATOR_MESSAGES,
)
BY_COMMAND: dict[tuple[int, int], Function] = {(f.cls, f.command): f for f in FUNCTIONS}

# ---- typed request builders (the client and the vector tests use these) --------------------------------

POSITION_TYPES = {"absolute": 4, "machine": 1, "relative": 6, "distance": 7}
PMC_ADR_TYPES = {letter: code for code, letter in enumerate(PMC_AREAS)}  # G0 F1 Y2 X3 A4 R5 T6 K7 C8 D9 ...
ALARM_TEXT_LEN = 64


def pmc_adr_type(area: str) -> int:
    try:
        return PMC_ADR_TYPES[area.upper()]
    except KeyError:
        raise ValueError(f"unknown PMC area {area!r}; expected one of {''.join(PMC_AREAS)}") from None


def read_macros_request(first: int, last: int) -> RequestSubpacket:
    return READ_MACROS.request(first, last)


def write_macros_request(first: int, values: Sequence[float | None],
                         exponent: int | None = None) -> RequestSubpacket:
    """cmd 0x16: scaled values for #first.. (exponent: force one, as HslCommunication's 3)."""
    extra = b"".join(encode_scaled(v, exponent) for v in values)
    return WRITE_MACROS.request(first, first + len(values) - 1, extra=extra)


def write_macro_double_request(number: int, value: float) -> RequestSubpacket:
    """cmd 0xa8 as pyfocas sends it: (number, 0, 0, 0, 8) + f64 BE."""
    return WRITE_MACRO_DOUBLE.request(number, extra=struct.pack(">d", value))


def read_pmc_request(area: str, start: int, end: int, data_type: int) -> RequestSubpacket:
    return READ_PMC.request(start, end, pmc_adr_type(area), data_type)


def write_pmc_request(area: str, start: int, data: bytes, data_type: int = 0) -> RequestSubpacket:
    return WRITE_PMC.request(start, start + len(data) - 1, pmc_adr_type(area), data_type, extra=data)


def read_clock_requests() -> tuple[RequestSubpacket, RequestSubpacket]:
    """Date and time are two subpackets of the same request."""
    return READ_CLOCK.request(CLOCK_DATE), READ_CLOCK.request(CLOCK_TIME)


def set_time_request(when: time) -> RequestSubpacket:
    """cmd 0x46 time form: args (1,0,0,0,12), extra 6 x 00 then hour, minute, second."""
    return SET_TIME.request(CLOCK_TIME, extra=_CLOCK.pack(0, 0, 0, when.hour, when.minute, when.second))


def read_records_request(fn: Function, first: int, last: int, axis: int) -> RequestSubpacket:
    return fn.request(first, last, axis)


def positions_request(kind: str, path: int = 1) -> RequestSubpacket:
    try:
        code = POSITION_TYPES[kind]
    except KeyError:
        expected = sorted(POSITION_TYPES)
        raise ValueError(f"unknown position kind {kind!r}; expected one of {expected}") from None
    return POSITIONS.request(code, ALL_AXES, path=path)


def alarm_messages_request(max_count: int, text_len: int = ALARM_TEXT_LEN) -> RequestSubpacket:
    return ALARM_MESSAGES.request(-1, max_count, 2, text_len)
