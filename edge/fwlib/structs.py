"""ctypes definitions of the FANUC C structs the library host passes to the FOCAS library.

Every layout is a fact from FANUC's public header fwlib32.h (its default branch: no FS15D, no PMCMEMD,
MAX_AXIS 32 as the Ethernet library for Linux defines it); the definitions are written here, not copied.
The ABI follows the platform's C compiler, as the vendor library was built with it:

- fwlib32.h packs to 4 only under MSVC (``#pragma pack(push, 4)`` inside ``#ifdef _MSC_VER``), so on
  Windows every struct gets ``_pack_ = 4``; the Linux builds use natural alignment.
- ``long`` is ``ctypes.c_long``: 8 bytes on x86-64 Linux, 4 on 32-bit ARM, x86 and Windows. So IODBPSD's
  union starts at offset 8 on x86-64 Linux (aligned for its ``long`` members) and at 4 elsewhere.

tests/fwlib/standin.c declares the same structs in C, and tests/unit/test_fwlib_layout.py compares sizeof
and every field offset the C compiler reports with these, so a slip on either side cannot hide.
"""

from __future__ import annotations

import ctypes
import sys
from typing import Any

MAX_AXIS = 32
ALMHIS_CHUNK = 10  # entries per call: the header sizes the ODBAHIS arrays "in case the number of data is 10"

_PACK: dict[str, Any] = {"_pack_": 4} if sys.platform == "win32" else {}


def _struct(name: str, fields: list[tuple[str, Any]]) -> type[ctypes.Structure]:
    return type(name, (ctypes.Structure,), {**_PACK, "_fields_": fields})


def _union(name: str, fields: list[tuple[str, Any]]) -> type[ctypes.Union]:
    return type(name, (ctypes.Union,), {**_PACK, "_fields_": fields})


_short, _ushort, _long, _char = ctypes.c_short, ctypes.c_ushort, ctypes.c_long, ctypes.c_char

# cnc_sysinfo
ODBSYS = _struct("ODBSYS", [
    ("addinfo", _short), ("max_axis", _short), ("cnc_type", _char * 2), ("mt_type", _char * 2),
    ("series", _char * 4), ("version", _char * 4), ("axes", _char * 2),
])
# cnc_statinfo (the default branch: hdck, tmmode, then the seven status fields)
ODBST = _struct("ODBST", [
    ("hdck", _short), ("tmmode", _short), ("aut", _short), ("run", _short), ("motion", _short),
    ("mstb", _short), ("emergency", _short), ("alarm", _short), ("edit", _short),
])
# real parameter data: value = prm_val / 10**dec_val
REALPRM = _struct("REALPRM", [("prm_val", _long), ("dec_val", _long)])
IODBPSD_U = _union("IODBPSD_U", [
    ("cdata", _char), ("idata", _short), ("ldata", _long), ("rdata", REALPRM),
    ("cdatas", _char * MAX_AXIS), ("idatas", _short * MAX_AXIS), ("ldatas", _long * MAX_AXIS),
    ("rdatas", REALPRM * MAX_AXIS),
])
# cnc_rdparam / cnc_wrparam / cnc_rddiag: datano, type (the axis), union u
IODBPSD = _struct("IODBPSD", [("datano", _short), ("type", _short), ("u", IODBPSD_U)])
# cnc_rdmacro: value = mcr_val / 10**dec_val
ODBM = _struct("ODBM", [("datano", _short), ("dummy", _short), ("mcr_val", _long), ("dec_val", _short)])
IODBPMC_U = _union("IODBPMC_U", [
    ("cdata", _char * 5), ("idata", _short * 5), ("ldata", _long * 5), ("fdata", ctypes.c_float * 5),
    ("dfdata", ctypes.c_double * 5),
])
# pmc_rdpmcrng / pmc_wrpmcrng; the host passes a longer buffer for more than 5 elements (length says how long)
IODBPMC = _struct("IODBPMC", [
    ("type_a", _short), ("type_d", _short), ("datano_s", _short), ("datano_e", _short), ("u", IODBPMC_U),
])
# cnc_alarm
ODBALM = _struct("ODBALM", [("dummy", _short * 2), ("data", _short)])
# cnc_rdalmmsg
ODBALMMSG = _struct("ODBALMMSG", [
    ("alm_no", _long), ("type", _short), ("axis", _short), ("dummy", _short), ("msg_len", _short),
    ("alm_msg", _char * 32),
])
# cnc_actf / cnc_acts
ODBACT = _struct("ODBACT", [("dummy", _short * 2), ("data", _long)])
# cnc_gettimer: type 0 reads the date, 1 the time
TIMER_DATE = _struct("TIMER_DATE", [("year", _short), ("month", _short), ("date", _short)])
TIMER_TIME = _struct("TIMER_TIME", [("hour", _short), ("minute", _short), ("second", _short)])
TIMER_DATA = _union("TIMER_DATA", [("date", TIMER_DATE), ("time", TIMER_TIME)])
IODBTIMER = _struct("IODBTIMER", [("type", _short), ("dummy", _short), ("data", TIMER_DATA)])

# Alarm history entries. cnc_rdalmhistry2 (ODBAHIS2), 3 (ODBAHIS3, adds pth_no) and 4 (ODBAHIS4, 64-byte
# message): all dates are shorts. Each ODBAHISn is {u16 s_no, u16 e_no, entry alm_his[10]}.
_ALMHIS_HEAD = [
    ("alm_grp", _short), ("alm_no", _short), ("axis_no", _short), ("year", _short), ("month", _short),
    ("day", _short), ("hour", _short), ("minute", _short), ("second", _short), ("len_msg", _short),
]
ALMHIS2_ENTRY = _struct("ALMHIS2_ENTRY", [*_ALMHIS_HEAD, ("alm_msg", _char * 32)])
ALMHIS3_ENTRY = _struct("ALMHIS3_ENTRY", [*_ALMHIS_HEAD, ("pth_no", _short), ("dummy", _short),
                                          ("alm_msg", _char * 32)])
ALMHIS4_ENTRY = _struct("ALMHIS4_ENTRY", [*_ALMHIS_HEAD, ("pth_no", _short), ("dummy", _short),
                                          ("alm_msg", _char * 64)])


def alarm_history_struct(entry: type[ctypes.Structure], name: str) -> type[ctypes.Structure]:
    return _struct(name, [("s_no", _ushort), ("e_no", _ushort), ("alm_his", entry * ALMHIS_CHUNK)])


ODBAHIS2 = alarm_history_struct(ALMHIS2_ENTRY, "ODBAHIS2")
ODBAHIS3 = alarm_history_struct(ALMHIS3_ENTRY, "ODBAHIS3")
ODBAHIS4 = alarm_history_struct(ALMHIS4_ENTRY, "ODBAHIS4")

# Every struct the host uses, by its fwlib32.h name: the layout test walks this table.
STRUCTS: dict[str, type[ctypes.Structure]] = {
    "ODBSYS": ODBSYS, "ODBST": ODBST, "REALPRM": REALPRM, "IODBPSD": IODBPSD, "ODBM": ODBM,
    "IODBPMC": IODBPMC, "ODBALM": ODBALM, "ODBALMMSG": ODBALMMSG, "ODBACT": ODBACT, "IODBTIMER": IODBTIMER,
    "ODBAHIS2": ODBAHIS2, "ODBAHIS3": ODBAHIS3, "ODBAHIS4": ODBAHIS4,
}


def field_layout(struct: type[ctypes.Structure | ctypes.Union], prefix: str = "") -> dict[str, tuple[int, int]]:
    """{dotted field path: (offset, size)} for every field, nested structs and unions included.

    Array members are described by their first element's nested fields (alm_his.alm_msg is alm_his[0]'s).
    """
    layout: dict[str, tuple[int, int]] = {}
    for name, ctype in struct._fields_:  # type: ignore[misc]
        descriptor = getattr(struct, name)
        path = f"{prefix}{name}"
        layout[path] = (descriptor.offset, descriptor.size)
        inner = getattr(ctype, "_type_", None) if issubclass(ctype, ctypes.Array) else ctype
        if isinstance(inner, type) and issubclass(inner, ctypes.Structure | ctypes.Union):
            for sub, (offset, size) in field_layout(inner, f"{path}.").items():
                layout[sub] = (descriptor.offset + offset, size)
    return layout
