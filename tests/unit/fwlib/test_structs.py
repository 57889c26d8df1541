"""The ctypes structs of edge.fwlib against the C compiler's layout of fwlib32.h's declarations.

tests/fwlib/standin.c declares every struct as fwlib32.h does and reports sizeof and each field's offset
and size as gcc laid them out; a slip on either side (a missing dummy, a short for a long, pack(4) on
Linux) fails here by name.
"""

from __future__ import annotations

import ctypes
import sys

import pytest

from edge.fwlib import structs as st
from tests.fwlib.standin import Standin, cross_layouts, standin_library


@pytest.fixture(scope="module")
def c_layouts() -> dict[str, dict[str, tuple[int, int]]]:
    return Standin(standin_library()).layouts()


@pytest.mark.parametrize("name", sorted(st.STRUCTS))
def test_sizeof_matches_the_c_compiler(name: str, c_layouts: dict[str, dict[str, tuple[int, int]]]) -> None:
    assert ctypes.sizeof(st.STRUCTS[name]) == c_layouts[name]["*"][1]


@pytest.mark.parametrize("name", sorted(st.STRUCTS))
def test_every_field_offset_and_size_matches(name: str, c_layouts: dict[str, dict[str, tuple[int, int]]]) -> None:
    ours = st.field_layout(st.STRUCTS[name])
    theirs = {field: at for field, at in c_layouts[name].items() if field != "*"}
    assert ours == theirs


def test_every_c_struct_is_checked(c_layouts: dict[str, dict[str, tuple[int, int]]]) -> None:
    assert set(c_layouts) == set(st.STRUCTS)


@pytest.mark.skipif(sys.platform == "win32" or ctypes.sizeof(ctypes.c_long) != 8, reason="x86-64/LP64 only")
def test_lp64_long_puts_the_iodbpsd_union_at_8() -> None:
    assert st.IODBPSD.u.offset == 8
    assert ctypes.sizeof(st.ODBM) == 24  # long mcr_val at 8, short dec_val at 16, padded to 8


def test_32_bit_x86_linux_layout_matches_ctypes_with_a_4_byte_long() -> None:
    """FANUC's x86 Linux build: gcc -m32 lays the same declarations out; ctypes built with a 4-byte long and
    natural alignment must agree (IODBPSD's union at 4, ODBM 12 bytes)."""
    order = [(struct, field) for struct, field, _, _ in Standin(standin_library()).layout_rows()]
    theirs = cross_layouts(["-m32"], order)
    ours = st.build(ctypes.c_int32, None)
    for name in st.TOP_LEVEL:
        assert ctypes.sizeof(ours[name]) == theirs[name]["*"][1], name
        assert st.field_layout(ours[name]) == {f: at for f, at in theirs[name].items() if f != "*"}, name
    assert theirs["IODBPSD"]["u"][0] == 4 and theirs["ODBM"]["*"][1] == 12
