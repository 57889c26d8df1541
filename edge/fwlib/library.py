"""Load FANUC's FOCAS library from the path the user gives, and declare the signatures the host calls.

FANUC ships the library with its FOCAS2 kit and does not allow redistribution: focas-edge never ships,
downloads or vendors it. Signatures are fwlib32.h's; every function returns a ``short`` EW_* code. On
Windows the library uses WINAPI (stdcall on 32-bit), so it is loaded with ``ctypes.WinDLL`` there.

A library that fails to load raises LibraryLoadError naming the path and, where the file is an ELF shared
object built for another machine (the usual mistake: FANUC's 32-bit ARM build under a 64-bit Python), both
architectures.
"""

from __future__ import annotations

import ctypes
import os
import platform
import struct
import sys
from typing import Any

from edge.fwlib import structs as st

_short, _ushort, _long = ctypes.c_short, ctypes.c_ushort, ctypes.c_long
_P = ctypes.POINTER

# name -> argtypes (restype is always short). Optional functions may be missing from a given build.
SIGNATURES: dict[str, list[Any]] = {
    "cnc_allclibhndl3": [ctypes.c_char_p, _ushort, _long, _P(_ushort)],
    "cnc_freelibhndl": [_ushort],
    "cnc_sysinfo": [_ushort, _P(st.ODBSYS)],
    "cnc_statinfo": [_ushort, _P(st.ODBST)],
    "cnc_rdparam": [_ushort, _short, _short, _short, _P(st.IODBPSD)],
    "cnc_wrparam": [_ushort, _short, _P(st.IODBPSD)],
    "cnc_rddiag": [_ushort, _short, _short, _short, _P(st.IODBPSD)],
    "cnc_rdmacro": [_ushort, _short, _short, _P(st.ODBM)],
    "cnc_wrmacro": [_ushort, _short, _short, _long, _short],
    "pmc_rdpmcrng": [_ushort, _short, _short, _ushort, _ushort, _ushort, _P(st.IODBPMC)],
    "pmc_wrpmcrng": [_ushort, _ushort, _P(st.IODBPMC)],
    "cnc_rdalmhisno": [_ushort, _P(_ushort)],
    "cnc_rdalmhistry2": [_ushort, _ushort, _ushort, _ushort, _P(st.ODBAHIS2)],
    "cnc_rdalmhistry3": [_ushort, _ushort, _ushort, _ushort, _P(st.ODBAHIS3)],
    "cnc_rdalmhistry4": [_ushort, _ushort, _ushort, _ushort, _P(st.ODBAHIS4)],
    "cnc_alarm": [_ushort, _P(st.ODBALM)],
    "cnc_rdalmmsg": [_ushort, _short, _P(_short), _P(st.ODBALMMSG)],
    "cnc_actf": [_ushort, _P(st.ODBACT)],
    "cnc_acts": [_ushort, _P(st.ODBACT)],
    "cnc_gettimer": [_ushort, _P(st.IODBTIMER)],
    "cnc_rdzofs": [_ushort, _short, _short, _short, _P(st.IODBZOFS)],
    "cnc_rdgcode": [_ushort, _short, _short, _P(_short), _P(st.ODBGCD)],
    "cnc_modal": [_ushort, _short, _short, _P(st.ODBMDL)],
}
REQUIRED = ("cnc_allclibhndl3", "cnc_freelibhndl", "cnc_sysinfo")
# Linux only: the library's process-wide set-up and tear-down (fwlib32.h declares them outside _WIN32).
STARTUP: tuple[str, list[Any]] = ("cnc_startupprocess", [_long, ctypes.c_char_p])
EXIT: tuple[str, list[Any]] = ("cnc_exitprocess", [])

# ELF e_machine values (the ELF specification) for the architectures FANUC builds the library for.
_ELF_MACHINES = {3: "x86 (32-bit)", 40: "ARM (32-bit)", 62: "x86-64", 183: "AArch64"}


class LibraryLoadError(Exception):
    """The FOCAS library could not be loaded or lacks a required function; the message says why."""


class FocasLibrary:
    """The loaded library: `call(name, *args)` returns the EW_* code; `has(name)` for optional functions."""

    def __init__(self, path: str, lib: Any) -> None:
        self.path = path
        self._functions: dict[str, Any] = {}
        for name, argtypes in [*SIGNATURES.items(), STARTUP, EXIT]:
            function = getattr(lib, name, None)
            if function is None:
                continue
            function.argtypes = argtypes
            function.restype = _short
            self._functions[name] = function
        missing = [name for name in REQUIRED if name not in self._functions]
        if missing:
            raise LibraryLoadError(f"{path}: not a FOCAS library, it lacks {', '.join(missing)}")

    def has(self, name: str) -> bool:
        return name in self._functions

    def call(self, name: str, *args: Any) -> int:
        return int(self._functions[name](*args))

    def startup(self, log_path: str) -> int:
        """cnc_startupprocess(0, log file) where the build has it (Linux); 0 where it does not."""
        if not self.has(STARTUP[0]):
            return 0
        return self.call(STARTUP[0], 0, log_path.encode())

    def exit(self) -> None:
        if self.has(EXIT[0]):
            self.call(EXIT[0])


def python_architecture() -> str:
    bits = struct.calcsize("P") * 8
    return f"{platform.machine() or 'unknown'} ({bits}-bit Python)"


def elf_architecture(path: str) -> str | None:
    """The machine an ELF file was built for, or None when the file is not ELF (or unreadable)."""
    try:
        with open(path, "rb") as handle:
            header = handle.read(20)
    except OSError:
        return None
    if len(header) < 20 or header[:4] != b"\x7fELF":
        return None
    order = "<" if header[5] == 1 else ">"
    (machine,) = struct.unpack_from(f"{order}H", header, 18)
    bits = {1: "32-bit", 2: "64-bit"}.get(header[4], "?")
    return _ELF_MACHINES.get(machine, f"ELF machine {machine} ({bits})")


def load_library(path: str) -> FocasLibrary:
    """Load the FOCAS library at `path`; LibraryLoadError with the reason (and architectures) otherwise."""
    if not os.path.exists(path):
        raise LibraryLoadError(
            f"FOCAS library {path}: no such file (FANUC ships it with the FOCAS2 kit; focas-edge does not "
            f"include it: give the path of your copy)"
        )
    loader: Any = ctypes.WinDLL if sys.platform == "win32" else ctypes.CDLL  # type: ignore[attr-defined]
    try:
        lib = loader(os.path.abspath(path))
    except OSError as exc:
        built_for = elf_architecture(path)
        hint = ""
        if built_for is not None:
            hint = (f"; the file is built for {built_for}; this Python is {python_architecture()} "
                    f"(the host must run under a Python of the library's architecture, docs/install.md §6)")
        raise LibraryLoadError(f"FOCAS library {path} could not be loaded: {exc}{hint}") from None
    return FocasLibrary(path, lib)
