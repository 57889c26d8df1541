"""ctypes definitions of the FANUC C structs the library host passes to the FOCAS library.

Every layout is a fact from FANUC's public header fwlib32.h (its default branch: no FS15D, no PMCMEMD,
MAX_AXIS 32 as the Ethernet library for Linux defines it); the definitions are written here, not copied.
The ABI follows the platform's C compiler, as the vendor library was built with it:

- fwlib32.h packs to 4 only under MSVC (``#pragma pack(push, 4)`` inside ``#ifdef _MSC_VER``), so on
  Windows every struct gets ``_pack_ = 4``; the Linux builds use natural alignment.
- ``long`` is ``ctypes.c_long``: 8 bytes on x86-64 Linux, 4 on 32-bit ARM, x86 and Windows. So IODBPSD's
  union starts at offset 8 on x86-64 Linux (aligned for its ``long`` members) and at 4 elsewhere.

tests/fwlib/standin.c declares the same structs in C, and tests/unit/fwlib/test_structs.py compares sizeof
and every field offset the C compiler reports with these, so a slip on either side cannot hide.
"""

from __future__ import annotations

import ctypes
import sys
from typing import Any

MAX_AXIS = 32
ALMHIS_CHUNK = 10  # entries per call: the header sizes the ODBAHIS arrays "in case the number of data is 10"

StructType = type[ctypes.Structure] | type[ctypes.Union]


def build(long_type: Any = ctypes.c_long, pack: int | None = None) -> dict[str, StructType]:
    """Every struct (and its nested types) for one ABI: C `long` as long_type, `#pragma pack(pack)` or natural.

    The module's own definitions are build() for the running platform; tests build others (a 4-byte long,
    as on 32-bit Linux) to compare with a cross-compiled layout.
    """
    extra: dict[str, Any] = {"_pack_": pack} if pack is not None else {}

    def struct(name: str, fields: list[tuple[str, Any]]) -> type[ctypes.Structure]:
        return type(name, (ctypes.Structure,), {**extra, "_fields_": fields})

    def union(name: str, fields: list[tuple[str, Any]]) -> type[ctypes.Union]:
        return type(name, (ctypes.Union,), {**extra, "_fields_": fields})

    short, ushort, long, char = ctypes.c_short, ctypes.c_ushort, long_type, ctypes.c_char
    t: dict[str, StructType] = {}
    # cnc_sysinfo
    t["ODBSYS"] = struct("ODBSYS", [
        ("addinfo", short), ("max_axis", short), ("cnc_type", char * 2), ("mt_type", char * 2),
        ("series", char * 4), ("version", char * 4), ("axes", char * 2),
    ])
    # cnc_statinfo (the default branch: hdck, tmmode, then the seven status fields)
    t["ODBST"] = struct("ODBST", [
        ("hdck", short), ("tmmode", short), ("aut", short), ("run", short), ("motion", short),
        ("mstb", short), ("emergency", short), ("alarm", short), ("edit", short),
    ])
    # real parameter data: value = prm_val / 10**dec_val
    realprm = t["REALPRM"] = struct("REALPRM", [("prm_val", long), ("dec_val", long)])
    t["IODBPSD_U"] = union("IODBPSD_U", [
        ("cdata", char), ("idata", short), ("ldata", long), ("rdata", realprm),
        ("cdatas", char * MAX_AXIS), ("idatas", short * MAX_AXIS), ("ldatas", long * MAX_AXIS),
        ("rdatas", realprm * MAX_AXIS),
    ])
    # cnc_rdparam / cnc_wrparam / cnc_rddiag: datano, type (the axis), union u
    t["IODBPSD"] = struct("IODBPSD", [("datano", short), ("type", short), ("u", t["IODBPSD_U"])])
    # cnc_rdmacro: value = mcr_val / 10**dec_val
    t["ODBM"] = struct("ODBM", [("datano", short), ("dummy", short), ("mcr_val", long), ("dec_val", short)])
    t["IODBPMC_U"] = union("IODBPMC_U", [
        ("cdata", char * 5), ("idata", short * 5), ("ldata", long * 5), ("fdata", ctypes.c_float * 5),
        ("dfdata", ctypes.c_double * 5),
    ])
    # pmc_rdpmcrng / pmc_wrpmcrng; the host passes a longer buffer for more than 5 elements (length says so)
    t["IODBPMC"] = struct("IODBPMC", [
        ("type_a", short), ("type_d", short), ("datano_s", short), ("datano_e", short), ("u", t["IODBPMC_U"]),
    ])
    # cnc_alarm
    t["ODBALM"] = struct("ODBALM", [("dummy", short * 2), ("data", short)])
    # cnc_rdalmmsg
    t["ODBALMMSG"] = struct("ODBALMMSG", [
        ("alm_no", long), ("type", short), ("axis", short), ("dummy", short), ("msg_len", short),
        ("alm_msg", char * 32),
    ])
    # cnc_actf / cnc_acts
    t["ODBACT"] = struct("ODBACT", [("dummy", short * 2), ("data", long)])
    # cnc_gettimer: type 0 reads the date, 1 the time
    date = struct("TIMER_DATE", [("year", short), ("month", short), ("date", short)])
    clock = struct("TIMER_TIME", [("hour", short), ("minute", short), ("second", short)])
    t["IODBTIMER"] = struct("IODBTIMER", [("type", short), ("dummy", short),
                                          ("data", union("TIMER_DATA", [("date", date), ("time", clock)]))])
    # cnc_rdzofs: one work-coordinate offset; type is the axis (-1 all), data in the least input increment
    t["IODBZOFS"] = struct("IODBZOFS", [("datano", short), ("type", short), ("data", long * MAX_AXIS)])
    # cnc_rdgcode: one modal G code (an array of them for type -1)
    t["ODBGCD"] = struct("ODBGCD", [("group", short), ("flag", short), ("code", char * 8)])
    # cnc_modal (default branch, not HSSB FS16WD): other-data types (100..) answer in modal.aux
    aux = struct("MODAL_AUX", [("aux_data", long), ("flag1", char), ("flag2", char)])
    t["ODBMDL"] = struct("ODBMDL", [("datano", short), ("type", short), ("modal", union("MODAL_U", [
        ("g_data", char), ("g_rdata", char * 35), ("g_1shot", char * 4), ("aux", aux), ("raux1", aux * 27),
        ("raux2", aux * MAX_AXIS)]))])
    # Alarm history: cnc_rdalmhistry2 (ODBAHIS2), 3 (ODBAHIS3, adds pth_no) and 4 (ODBAHIS4, 64-byte message);
    # all dates are shorts. Each ODBAHISn is {u16 s_no, u16 e_no, entry alm_his[10]}.
    head = [
        ("alm_grp", short), ("alm_no", short), ("axis_no", short), ("year", short), ("month", short),
        ("day", short), ("hour", short), ("minute", short), ("second", short), ("len_msg", short),
    ]
    entries = {
        2: struct("ALMHIS2_ENTRY", [*head, ("alm_msg", char * 32)]),
        3: struct("ALMHIS3_ENTRY", [*head, ("pth_no", short), ("dummy", short), ("alm_msg", char * 32)]),
        4: struct("ALMHIS4_ENTRY", [*head, ("pth_no", short), ("dummy", short), ("alm_msg", char * 64)]),
    }
    for version, entry in entries.items():
        t[f"ODBAHIS{version}"] = struct(f"ODBAHIS{version}", [("s_no", ushort), ("e_no", ushort),
                                                              ("alm_his", entry * ALMHIS_CHUNK)])
    return t


# The running platform's ABI: MSVC's pack(4) on Windows, natural alignment elsewhere.
_PLATFORM = build(ctypes.c_long, 4 if sys.platform == "win32" else None)
ODBSYS: Any = _PLATFORM["ODBSYS"]
ODBST: Any = _PLATFORM["ODBST"]
REALPRM: Any = _PLATFORM["REALPRM"]
IODBPSD_U: Any = _PLATFORM["IODBPSD_U"]
IODBPSD: Any = _PLATFORM["IODBPSD"]
ODBM: Any = _PLATFORM["ODBM"]
IODBPMC: Any = _PLATFORM["IODBPMC"]
ODBALM: Any = _PLATFORM["ODBALM"]
ODBALMMSG: Any = _PLATFORM["ODBALMMSG"]
ODBACT: Any = _PLATFORM["ODBACT"]
IODBTIMER: Any = _PLATFORM["IODBTIMER"]
IODBZOFS: Any = _PLATFORM["IODBZOFS"]
ODBGCD: Any = _PLATFORM["ODBGCD"]
ODBMDL: Any = _PLATFORM["ODBMDL"]
ODBAHIS2: Any = _PLATFORM["ODBAHIS2"]
ODBAHIS3: Any = _PLATFORM["ODBAHIS3"]
ODBAHIS4: Any = _PLATFORM["ODBAHIS4"]

# The structs the library calls take, by their fwlib32.h name: the layout test walks this table.
TOP_LEVEL = ("ODBSYS", "ODBST", "REALPRM", "IODBPSD", "ODBM", "IODBPMC", "ODBALM", "ODBALMMSG", "ODBACT",
             "IODBTIMER", "IODBZOFS", "ODBGCD", "ODBMDL", "ODBAHIS2", "ODBAHIS3", "ODBAHIS4")
STRUCTS: dict[str, StructType] = {name: _PLATFORM[name] for name in TOP_LEVEL}


def field_layout(struct: StructType, prefix: str = "") -> dict[str, tuple[int, int]]:
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
