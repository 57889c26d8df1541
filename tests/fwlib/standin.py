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
LAYOUT_SOURCE = HERE / "layouts.c"
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


def cross_layouts(flags: list[str], order: list[tuple[str, str]]) -> dict[str, dict[str, tuple[int, int]]]:
    """The layouts gcc chooses with `flags` (e.g. -m32), read from its assembly of layouts.c.

    `order` is the (struct, field) sequence of the table (the native stand-in's, same X-macro); the test
    skips when gcc cannot compile for that ABI.
    """
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed")
    result = subprocess.run([gcc, *flags, "-S", "-o", "-", str(LAYOUT_SOURCE)], capture_output=True, text=True,
                            timeout=120)
    if result.returncode != 0:
        pytest.skip(f"gcc {' '.join(flags)} cannot compile here: {result.stderr.strip()[:200]}")
    numbers = [int(line.split()[1]) - 1 for line in result.stdout.splitlines()
               if line.strip().startswith(".long")]
    structs = sorted({struct for struct, _ in order}, key=[s for s, _ in order].index)
    fields = [(struct, field) for struct, field in order if field != "*"]
    assert len(numbers) == 2 * len(fields) + len(structs), "layouts.c and the stand-in's table disagree"
    table: dict[str, dict[str, tuple[int, int]]] = {}
    for index, (struct, field) in enumerate(fields):
        table.setdefault(struct, {})[field] = (numbers[2 * index], numbers[2 * index + 1])
    for index, struct in enumerate(structs):
        table[struct]["*"] = (0, numbers[2 * len(fields) + index])
    return table


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
        self.lib.standin_set_work_offset.argtypes = [ctypes.c_short, ctypes.c_short, ctypes.c_long]
        self.lib.standin_last_rdzofs_length.restype = ctypes.c_short
        self.lib.standin_set_tool.argtypes = [ctypes.c_long]
        self.lib.standin_hang_history.argtypes = [ctypes.c_int]
        self.lib.standin_fail_history.argtypes = [ctypes.c_short, ctypes.c_int]
        self.lib.standin_reset()

    def layout_rows(self) -> list[tuple[str, str, int, int]]:
        """(struct, field path or '*', offset, size) in the table's order, as the C compiler laid them out."""
        rows = []
        for line in self.lib.standin_layouts().decode().splitlines():
            struct, field, offset, size = line.split()
            rows.append((struct, field, int(offset), int(size)))
        return rows

    def layouts(self) -> dict[str, dict[str, tuple[int, int]]]:
        """{struct: {field path or '*': (offset, size)}}."""
        table: dict[str, dict[str, tuple[int, int]]] = {}
        for struct, field, offset, size in self.layout_rows():
            table.setdefault(struct, {})[field] = (offset, size)
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
