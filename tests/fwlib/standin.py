"""Build and drive the stand-in FOCAS library (tests/fwlib/standin.c): a test fixture, never shipped.

`standin_library()` compiles it once per test session with gcc (running scripts/ensure-gcc.sh first where
gcc is missing) and skips the calling test, saying why, when no compiler can be had.
"""

from __future__ import annotations

import ctypes
import functools
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "standin.c"
ENSURE_GCC = HERE.parent.parent / "scripts" / "ensure-gcc.sh"


@functools.cache
def _build() -> tuple[str | None, str]:
    if shutil.which("gcc") is None and ENSURE_GCC.exists():
        subprocess.run(["bash", str(ENSURE_GCC)], check=False, capture_output=True, timeout=900)
    gcc = shutil.which("gcc")
    if gcc is None:
        return None, "gcc is not installed (scripts/ensure-gcc.sh could not install it)"
    out = Path(tempfile.mkdtemp(prefix="fwlib-standin-")) / "libfwlib-standin.so"
    result = subprocess.run([gcc, "-shared", "-fPIC", "-O1", "-pthread", "-Wall", "-Werror", "-o", str(out),
                             str(SOURCE)], capture_output=True, text=True, timeout=120)
    if result.returncode != 0:
        return None, f"gcc could not build the stand-in library: {result.stderr.strip()}"
    return str(out), ""


def standin_library() -> str:
    """The path of the compiled stand-in (the test skips when there is no compiler)."""
    path, reason = _build()
    if path is None:
        pytest.skip(reason)
    return path


class Standin:
    """The stand-in's control hooks (state set-up, injected faults) over ctypes."""

    def __init__(self, path: str) -> None:
        self.lib = ctypes.CDLL(path)
        self.lib.standin_layouts.restype = ctypes.c_char_p
        self.lib.standin_param_value.restype = ctypes.c_long
        self.lib.standin_param_value.argtypes = [ctypes.c_short]
        self.lib.standin_set_param.argtypes = [ctypes.c_short, ctypes.c_short, ctypes.c_long, ctypes.c_long]
        self.lib.standin_push_alarm.argtypes = [ctypes.c_short] * 9 + [ctypes.c_char_p, ctypes.c_short]
        self.lib.standin_set_pmc.argtypes = [ctypes.c_short, ctypes.c_ushort, ctypes.c_ubyte]
        self.lib.standin_pmc.argtypes = [ctypes.c_short, ctypes.c_ushort]
        self.lib.standin_calls.argtypes = [ctypes.c_char_p]
        self.lib.standin_reset()

    def layouts(self) -> dict[str, dict[str, tuple[int, int]]]:
        """{struct: {field path or '*': (offset, size)}} as the C compiler laid them out."""
        table: dict[str, dict[str, tuple[int, int]]] = {}
        for line in self.lib.standin_layouts().decode().splitlines():
            struct, field, offset, size = line.split()
            table.setdefault(struct, {})[field] = (int(offset), int(size))
        return table

    def set_param(self, number: int, ptype: int, value: int, dec: int = 0) -> None:
        self.lib.standin_set_param(number, ptype, value, dec)

    def param(self, number: int) -> int:
        return int(self.lib.standin_param_value(number))

    def push_alarm(self, when: tuple[int, int, int, int, int, int], alm_no: int, message: bytes,
                   axis: int = 0, group: int = 2, length: int = -1) -> None:
        self.lib.standin_push_alarm(*when, axis, group, alm_no, message, length)

    def calls(self, name: str) -> int:
        return int(self.lib.standin_calls(name.encode()))

    def __getattr__(self, name: str) -> object:
        return getattr(self.lib, f"standin_{name}")
