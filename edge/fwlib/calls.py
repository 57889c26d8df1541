"""Translate one packed-surface request into FOCAS library calls on one handle, and the result back.

Runs on the handle's worker thread (edge.fwlib.worker), never on the event loop. Payloads are decoded and
answers encoded with the same codecs the client and the simulator use (edge.focas.packed); this module
only moves fields between those codecs and fwlib32.h's C structs (edge.fwlib.structs).

EW_* codes pass through as the surface's statuses, which number them as fwlib32.h does, except EW_PASSWD
(17), which the seed's surface sends as 11 (docs/packed-protocol.md §3.5). A command the host has no
translation for, or whose library function this build lacks, answers EW_FUNC.

What the library cannot tell us: the data type of a parameter (cnc_rdparam fills a union without saying
which member). The host takes it from its configuration (`params:` / `diag:` per machine) and answers
EW_ATTRIB, naming the number in its log, for a number it has no type for, rather than guess a width that a
write would then be trusted with.
"""

from __future__ import annotations

import ctypes
import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from edge.focas import packed as pk
from edge.focas.errors import EW_ATTRIB, EW_BUSY, EW_FUNC, EW_LENGTH, EW_NOOPT, EW_OK, CncError, ProtocolError
from edge.focas.functions import PMC_ADR_TYPES
from edge.focas.model import ActiveAlarm, ModalGCode, ParamRecord, ParamType, PmcType, SysInfo
from edge.focas.packed.endpoint import error_answer, error_status
from edge.fwlib import structs as st
from edge.fwlib.library import FocasLibrary

log = logging.getLogger(__name__)


@dataclass
class LibraryCnc:
    """One CNC behind the library: its handle, and the parameter types the host was configured with."""

    library: FocasLibrary
    handle: int
    param_types: dict[int, ParamType] = field(default_factory=dict)
    diag_types: dict[int, ParamType] = field(default_factory=dict)
    input_decimals: int = 3  # cnc_rdzofs answers integers in the least input increment (configured)
    axis_count: int | None = None  # controlled axes, from cnc_sysinfo's `axes`; None until read
    history_version: int | None = None  # the cnc_rdalmhistryN this control answered; None until tried
    lost_code: int = 0  # the negative EW_* code that said the handle is gone (the worker reconnects)

    def call(self, function: str, *args: Any) -> None:
        if not self.library.has(function):
            raise CncError(EW_FUNC, function)
        code = self.library.call(function, self.handle, *args)
        if code != EW_OK:
            if is_connection_lost(code):
                self.lost_code = code
            raise CncError(code, function)


Translation = Callable[[LibraryCnc, bytes], bytes]


def _text(raw: bytes) -> str:
    return raw.decode("ascii", errors="replace")


def _sysinfo(cnc: LibraryCnc, payload: bytes) -> bytes:
    info = st.ODBSYS()
    cnc.call("cnc_sysinfo", ctypes.byref(info))
    return pk.read_response(pk.encode_sysinfo(SysInfo(
        info.addinfo, info.max_axis, _text(info.cnc_type), _text(info.mt_type), _text(info.series),
        _text(info.version), _text(info.axes))))


def _statinfo(cnc: LibraryCnc, payload: bytes) -> bytes:
    stat = st.ODBST()
    cnc.call("cnc_statinfo", ctypes.byref(stat))
    return pk.read_response(pk.encode_cncstat(pk.CncStatus(
        stat.hdck, stat.tmmode, stat.aut, stat.run, stat.motion, stat.mstb, stat.emergency, stat.alarm,
        stat.edit)))


# ---- parameters and diagnosis: IODBPSD ----------------------------------------------------------------
_PSD_MEMBER: dict[ParamType, str] = {
    ParamType.BIT: "cdata", ParamType.BYTE: "cdata", ParamType.WORD: "idata", ParamType.TWO_WORD: "ldata",
    ParamType.REAL: "rdata",
}


def psd_length(ptype: ParamType) -> int:
    """The `length` argument for one value: the header up to the union, plus the member's size."""
    member = _PSD_MEMBER[ptype]
    return st.IODBPSD.u.offset + getattr(st.IODBPSD_U, member).size


def _type_of(table: dict[int, ParamType], number: int, what: str) -> ParamType:
    ptype = table.get(number)
    if ptype is None:
        log.warning("%s %d has no data type in the library host's configuration; answering EW_ATTRIB",
                    what, number)
        raise CncError(EW_ATTRIB, what)
    return ptype


def _psd_value(psd: Any, ptype: ParamType) -> int | float:
    if ptype == ParamType.REAL:
        return pk.from_scaled(psd.u.rdata.prm_val, psd.u.rdata.dec_val)
    if ptype in (ParamType.BIT, ParamType.BYTE):
        raw = psd.u.cdata[0]
        return raw if ptype == ParamType.BIT else (raw - 256 if raw > 127 else raw)
    return int(getattr(psd.u, _PSD_MEMBER[ptype]))


def _read_psd(cnc: LibraryCnc, payload: bytes, function: str, table: dict[int, ParamType]) -> bytes:
    number, axis = pk.decode_param_read(payload)
    if axis < 0:  # all axes needs the control's axis count and the *datas arrays: not translated yet
        raise CncError(EW_ATTRIB, function)
    ptype = _type_of(table, number, function)
    psd = st.IODBPSD()
    cnc.call(function, number, axis, psd_length(ptype), ctypes.byref(psd))
    record = ParamRecord(number, axis, int(ptype), (_psd_value(psd, ptype),))
    return pk.read_response(pk.encode_param_record(record))


def _rdparam(cnc: LibraryCnc, payload: bytes) -> bytes:
    return _read_psd(cnc, payload, "cnc_rdparam", cnc.param_types)


def _rddiag(cnc: LibraryCnc, payload: bytes) -> bytes:
    return _read_psd(cnc, payload, "cnc_rddiag", cnc.diag_types)


def _wrparam(cnc: LibraryCnc, payload: bytes) -> bytes:
    request = pk.decode_param_write(payload)
    ptype = _type_of(cnc.param_types, request.number, "cnc_wrparam")
    if len(request.data) != pk.param_width(ptype):
        raise CncError(EW_LENGTH, "cnc_wrparam")
    value = request.value_as(ptype)
    psd = st.IODBPSD()
    psd.datano, psd.type = request.number, request.axis
    if ptype == ParamType.REAL:
        psd.u.rdata.prm_val, psd.u.rdata.dec_val = pk.to_scaled(value, "cnc_wrparam")
    elif ptype in (ParamType.BIT, ParamType.BYTE):
        psd.u.cdata = bytes([int(value) & 0xFF])
    else:
        setattr(psd.u, _PSD_MEMBER[ptype], int(value))
    cnc.call("cnc_wrparam", psd_length(ptype), ctypes.byref(psd))
    return pk.encode_status(EW_OK)


# ---- macros: ODBM ----------------------------------------------------------------------------------------
ODBM_WRITE_LENGTH = 10  # cnc_wrmacro's length argument, as FANUC documents it (the Windows sizeof(ODBM))


def _rdmacro(cnc: LibraryCnc, payload: bytes) -> bytes:
    number = pk.decode_macro_read(payload)
    odbm = st.ODBM()
    cnc.call("cnc_rdmacro", number, ctypes.sizeof(odbm), ctypes.byref(odbm))
    value = None if odbm.dec_val < 0 else pk.from_scaled(odbm.mcr_val, odbm.dec_val)
    return pk.read_response(pk.encode_macro(number, value))


def _wrmacro(cnc: LibraryCnc, payload: bytes) -> bytes:
    number, mantissa, decimals = pk.decode_macro_raw(payload, "cnc_wrmacro")
    cnc.call("cnc_wrmacro", number, ODBM_WRITE_LENGTH, mantissa, decimals)
    return pk.encode_status(EW_OK)


# ---- PMC: IODBPMC ---------------------------------------------------------------------------------------
_IODBPMC_HEAD = st.IODBPMC.u.offset
def _pmc_buffer(data_bytes: int) -> Any:
    """An IODBPMC with room for data_bytes of data (the header's array holds five elements only)."""
    size = max(ctypes.sizeof(st.IODBPMC), _IODBPMC_HEAD + data_bytes)
    raw = (ctypes.c_char * size)()
    return raw, ctypes.cast(raw, ctypes.POINTER(st.IODBPMC))


def _adr_type(area: str, function: str) -> int:
    code = PMC_ADR_TYPES.get(area)
    if code is None:
        raise CncError(EW_ATTRIB, function)
    return code


def _rdpmcrng(cnc: LibraryCnc, payload: bytes) -> bytes:
    rng = pk.decode_pmc_range(payload, False, "pmc_rdpmcrng")
    try:
        kind = PmcType(rng.data_type)
    except ValueError:
        raise CncError(EW_ATTRIB, "pmc_rdpmcrng") from None
    if rng.byte_count % kind.width:
        raise CncError(EW_LENGTH, "pmc_rdpmcrng")
    raw, pmc = _pmc_buffer(rng.byte_count)
    cnc.call("pmc_rdpmcrng", _adr_type(rng.area, "pmc_rdpmcrng"), kind, rng.start, rng.end,
             _IODBPMC_HEAD + rng.byte_count, pmc)
    data = bytes(raw)[_IODBPMC_HEAD : _IODBPMC_HEAD + rng.byte_count]
    values = struct.unpack(f"={rng.byte_count // kind.width}{kind.struct_code}", data)
    little = struct.pack(f"<{len(values)}{kind.struct_code}", *values)  # the surface is little-endian
    return pk.read_response(pk.encode_pmc_range(pk.PmcRange(rng.area, kind, rng.start, rng.end, little)))


def _wrpmcrng(cnc: LibraryCnc, payload: bytes) -> bytes:
    rng = pk.decode_pmc_range(payload, True, "pmc_wrpmcrng")
    if rng.data_type != PmcType.BYTE:
        raise CncError(EW_ATTRIB, "pmc_wrpmcrng")
    if rng.byte_count > pk.PMC_MAX_WRITE:
        raise CncError(EW_LENGTH, "pmc_wrpmcrng")
    raw, pmc = _pmc_buffer(rng.byte_count)
    pmc.contents.type_a = _adr_type(rng.area, "pmc_wrpmcrng")
    pmc.contents.type_d = PmcType.BYTE
    # datano_s/e are shorts in the default IODBPMC: addresses above 32767 travel as their bit pattern
    pmc.contents.datano_s = ctypes.c_short(rng.start).value
    pmc.contents.datano_e = ctypes.c_short(rng.end).value
    ctypes.memmove(ctypes.addressof(raw) + _IODBPMC_HEAD, rng.data, rng.byte_count)
    cnc.call("pmc_wrpmcrng", _IODBPMC_HEAD + rng.byte_count, pmc)
    return pk.encode_status(EW_OK)


# ---- alarm history: ODBAHIS2/3/4 -> the seed's ODBALMHIS ------------------------------------------------
# Newest first in the order tried: a control that lacks one answers EW_FUNC or EW_NOOPT (or the build lacks
# the symbol), and the next is tried once; the one that worked is kept for that handle.
HISTORY_FUNCTIONS: list[tuple[int, str, type[ctypes.Structure]]] = [
    (4, "cnc_rdalmhistry4", st.ODBAHIS4),
    (3, "cnc_rdalmhistry3", st.ODBAHIS3),
    (2, "cnc_rdalmhistry2", st.ODBAHIS2),
]
_NOT_THERE = (EW_FUNC, EW_NOOPT)


def _history_row(entry: Any) -> pk.AlarmHistoryRow:
    capacity = len(entry.alm_msg)
    length = min(max(entry.len_msg, 0), capacity)
    message = ctypes.string_at(ctypes.addressof(entry) + type(entry).alm_msg.offset, length)
    return pk.AlarmHistoryRow(entry.year, entry.month, entry.day, entry.hour, entry.minute, entry.second,
                              entry.axis_no, entry.alm_grp, entry.alm_no, message)


def _history_chunk(cnc: LibraryCnc, version: int, first: int, last: int) -> list[pk.AlarmHistoryRow]:
    _, function, struct_type = next(f for f in HISTORY_FUNCTIONS if f[0] == version)
    buffer = struct_type()
    cnc.call(function, first, last, ctypes.sizeof(buffer), ctypes.byref(buffer))
    count = max(0, min(buffer.e_no - buffer.s_no + 1, st.ALMHIS_CHUNK)) if buffer.e_no >= buffer.s_no else 0
    return [_history_row(buffer.alm_his[i]) for i in range(count)]


def _choose_history_version(cnc: LibraryCnc) -> int:
    for version, function, _ in HISTORY_FUNCTIONS:
        if not cnc.library.has(function):
            continue
        try:
            _history_chunk(cnc, version, 1, 1)
        except CncError as exc:
            if exc.code in _NOT_THERE:
                continue
            raise
        return version
    raise CncError(EW_FUNC, "cnc_rdalmhistry")


def _rdalmhistry(cnc: LibraryCnc, payload: bytes) -> bytes:
    depth = pk.decode_alarm_history_request(payload)
    if cnc.history_version is None:
        cnc.history_version = _choose_history_version(cnc)
    count = ctypes.c_ushort()
    cnc.call("cnc_rdalmhisno", ctypes.byref(count))
    wanted = min(depth, count.value)
    rows: list[pk.AlarmHistoryRow] = []
    for first in range(1, wanted + 1, st.ALMHIS_CHUNK):
        last = min(first + st.ALMHIS_CHUNK - 1, wanted)
        chunk = _history_chunk(cnc, cnc.history_version, first, last)
        rows.extend(chunk)
        if len(chunk) < last - first + 1:
            break  # the ring is shorter than the count said (it moved between calls)
    return pk.encode_alarm_history_rows(rows)


# ---- small reads ------------------------------------------------------------------------------------------
def _alarm(cnc: LibraryCnc, payload: bytes) -> bytes:
    alm = st.ODBALM()
    cnc.call("cnc_alarm", ctypes.byref(alm))
    return pk.read_response(pk.encode_int32(alm.data & 0xFFFF))


def _rdalmmsg(cnc: LibraryCnc, payload: bytes) -> bytes:
    wanted = max(0, min(pk.decode_i16_request(payload, "cnc_rdalmmsg request"), 64))
    count = ctypes.c_short(wanted)
    messages = (st.ODBALMMSG * max(wanted, 1))()
    cnc.call("cnc_rdalmmsg", -1, ctypes.byref(count), messages)
    alarms = []
    for message in messages[: max(0, min(count.value, wanted))]:
        text = bytes(message.alm_msg)[: min(max(message.msg_len, 0), 32)]
        alarms.append(ActiveAlarm(message.alm_no, message.type, message.axis, _text(text)))
    return pk.read_response(pk.encode_alarm_messages(alarms))


def _act(function: str) -> Translation:
    def read(cnc: LibraryCnc, payload: bytes) -> bytes:
        act = st.ODBACT()
        cnc.call(function, ctypes.byref(act))
        return pk.read_response(pk.encode_float(float(act.data)))
    return read


def _gettime(cnc: LibraryCnc, payload: bytes) -> bytes:
    """Date and time are two calls: read date, time, date again, and retry once across midnight."""
    for _ in range(2):
        before, clock, after = st.IODBTIMER(type=0), st.IODBTIMER(type=1), st.IODBTIMER(type=0)
        for timer in (before, clock, after):
            cnc.call("cnc_gettimer", ctypes.byref(timer))
        day = (before.data.date.year, before.data.date.month, before.data.date.date)
        if day == (after.data.date.year, after.data.date.month, after.data.date.date):
            break
    fields = (*day, clock.data.time.hour, clock.data.time.minute, clock.data.time.second)
    return pk.read_response(struct.pack("<6h", *fields))


def _axis_count(cnc: LibraryCnc) -> int:
    """Controlled axes (ODBSYS.axes, two ASCII digits), read once per handle; at most MAX_AXIS."""
    if cnc.axis_count is None:
        info = st.ODBSYS()
        cnc.call("cnc_sysinfo", ctypes.byref(info))
        digits = _text(info.axes).strip()
        cnc.axis_count = max(0, min(int(digits), st.MAX_AXIS)) if digits.isdigit() else st.MAX_AXIS
    return cnc.axis_count


def _rdzofs(cnc: LibraryCnc, payload: bytes) -> bytes:
    """One work offset for every axis (type -1); integers in the least input increment become mm/inch."""
    number = pk.decode_i16_request(payload, "cnc_rdzofs request")
    axes = _axis_count(cnc)
    zofs = st.IODBZOFS()
    length = st.IODBZOFS.data.offset + axes * (st.IODBZOFS.data.size // st.MAX_AXIS)
    cnc.call("cnc_rdzofs", number, -1, length, ctypes.byref(zofs))
    return pk.read_response(pk.encode_floats([pk.from_scaled(v, cnc.input_decimals) for v in zofs.data[:axes]]))


MAX_G_GROUPS = 64  # room for every modal group cnc_rdgcode answers (the header's raux1 holds 27)
GCODE_ALL_GROUPS, ACTIVE_BLOCK = -1, 1  # cnc_rdgcode type and block as FOCAS users pass them


def _rdgcode(cnc: LibraryCnc, payload: bytes) -> bytes:
    """Every modal group's G code of the active block; an empty code (group not in use) is left out."""
    count = ctypes.c_short(MAX_G_GROUPS)
    codes = (st.ODBGCD * MAX_G_GROUPS)()
    cnc.call("cnc_rdgcode", GCODE_ALL_GROUPS, ACTIVE_BLOCK, ctypes.byref(count), codes)
    answered = [codes[i] for i in range(max(0, min(count.value, MAX_G_GROUPS)))]
    modal = [ModalGCode(c.group, _text(bytes(c.code).split(b"\x00", 1)[0]).strip()) for c in answered]
    return pk.read_response(pk.encode_modal_g_codes([m for m in modal if m.code]))


MODAL_T_CODE, MODAL_ACTIVE_BLOCK = 108, 0  # cnc_modal type of address T; block 0 = the active block


def _tool_number(cnc: LibraryCnc, payload: bytes) -> bytes:
    modal = st.ODBMDL()
    cnc.call("cnc_modal", MODAL_T_CODE, MODAL_ACTIVE_BLOCK, ctypes.byref(modal))
    return pk.read_response(pk.encode_int32(int(modal.modal.aux.aux_data)))


TRANSLATIONS: dict[int, Translation] = {
    pk.Command.SYSINFO: _sysinfo,
    pk.Command.RDCNCSTAT: _statinfo,
    pk.Command.RDPARAM: _rdparam,
    pk.Command.RDDIAG: _rddiag,
    pk.Command.WRPARAM: _wrparam,
    pk.Command.RDMACRO: _rdmacro,
    pk.Command.WRMACRO: _wrmacro,
    pk.Command.RDPMCRNG: _rdpmcrng,
    pk.Command.WRPMCRNG: _wrpmcrng,
    pk.Command.RDALMHISTRY: _rdalmhistry,
    pk.Command.ALARM: _alarm,
    pk.Command.RDALMMSG: _rdalmmsg,
    pk.Command.ACTF: _act("cnc_actf"),
    pk.Command.ACTS: _act("cnc_acts"),
    pk.Command.GETTIME: _gettime,
    pk.Command.RDZOFS: _rdzofs,
    pk.Command.RDGCODE: _rdgcode,
    pk.Command.RDTOOLNUM: _tool_number,
}


def answer(cnc: LibraryCnc, command: int, payload: bytes) -> bytes:
    """The response payload for one request; a library failure becomes its status, never an exception."""
    translation = TRANSLATIONS.get(command)
    if translation is None:
        return pk.encode_status(EW_FUNC)
    try:
        return translation(cnc, payload)
    except (CncError, ProtocolError) as exc:  # the library's EW_* code, or a payload the codecs refused
        return error_answer(command, error_status(exc))


def is_connection_lost(code: int) -> bool:
    """Negative EW_* codes (socket, handle, protocol ...) mean the handle is gone; EW_BUSY (-1) does not."""
    return code < EW_BUSY
