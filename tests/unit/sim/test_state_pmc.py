"""The simulated machine's PMC memory: area sizes, write rules, typed reads, signals following the machine."""

from __future__ import annotations

import pytest

from edge.focas.errors import (
    EW_ATTRIB,
    EW_LENGTH,
    EW_NUMBER,
    LengthError,
    OutOfRange,
)
from edge.focas.model import PmcType
from tests.unit.sim.helpers import machine


def test_pmc_areas_have_realistic_sizes() -> None:
    state, _ = machine("30i")
    assert set("GFYXARTKCDE") <= set(state.profile.pmc_sizes)
    assert state.pmc_size("R") == 8000 and state.pmc_size("D") == 10000 and state.pmc_size("X") == 128
    assert machine("16i")[0].pmc_size("E") == 8000


def test_pmc_write_rules() -> None:
    state, _ = machine()
    state.write_pmc("R", 200, bytes(range(32)))
    assert state.read_pmc_bytes("R", 200, 231) == bytes(range(32))
    with pytest.raises(LengthError) as caught:
        state.write_pmc("R", 200, bytes(33))
    assert caught.value.code == EW_LENGTH
    with pytest.raises(OutOfRange) as outside:
        state.write_pmc("R", 7999, b"\x01\x02")  # runs past R7999
    assert outside.value.code == EW_NUMBER
    with pytest.raises(OutOfRange) as area:
        state.write_pmc("M", 0, b"\x01")
    assert area.value.code == EW_ATTRIB
    assert [(w.target, w.old, w.new) for w in state.writes("pmc:")] == [
        ("pmc:R200-R231", bytes(32), bytes(range(32)))]


def test_pmc_typed_reads() -> None:
    state, _ = machine()
    state.write_pmc("D", 100, b"\xff\xfe\x00\x00\x01\x00\x3f\x80\x00\x00")
    assert state.read_pmc("D", 100, 101, PmcType.WORD) == [-2]
    assert state.read_pmc("D", 102, 105, PmcType.LONG) == [256]
    assert state.read_pmc("D", 106, 109, PmcType.FLOAT) == [1.0]
    assert state.read_pmc("D", 100, 101, PmcType.BYTE) == [255, 254]
    assert state.read_pmc("D", 2204, 2205, PmcType.WORD) == [600]
    with pytest.raises(LengthError):
        state.read_pmc("D", 100, 100, PmcType.WORD)
    with pytest.raises(OutOfRange) as no_float:
        machine("16i")[0].read_pmc("D", 0, 3, PmcType.FLOAT)
    assert no_float.value.code == EW_ATTRIB


def test_pmc_signals_follow_the_machine() -> None:
    state, clock = machine()
    clock.tick(3.0)
    assert state.read_pmc_bytes("F", 0, 0)[0] & 0b0010_0000  # STL while cutting
    clock.tick(9.0)
    assert not state.read_pmc_bytes("F", 0, 0)[0] & 0b0010_0000
