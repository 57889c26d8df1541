"""The simulated machine's macro variables: reads, writes and their log, numbers outside the ranges."""

from __future__ import annotations

import pytest

from edge.focas.errors import (
    EW_NUMBER,
    OutOfRange,
)
from tests.unit.sim.helpers import T0, machine


def test_macros_read_write_and_log() -> None:
    state, clock = machine()
    assert state.read_macros(500, 502) == [12.5, 0.0, 3.0]
    assert state.read_macro(150) is None  # vacant
    clock.tick(1.0)
    state.write_macro(150, 1.25)
    state.write_macro(500, None, protocol="packed")
    assert state.read_macros(150, 150) == [1.25]
    assert state.read_macro(500) is None
    log = state.writes("macro:")
    assert [(w.time, w.protocol, w.target, w.old, w.new) for w in log] == [
        (T0 + 1.0, "native", "macro:150", None, 1.25),
        (T0 + 1.0, "packed", "macro:500", 12.5, None),
    ]


@pytest.mark.parametrize(("first", "last"), [(1, 1), (99, 100), (200, 200), (199, 500), (1000, 1000), (5, 4)])
def test_macro_numbers_outside_the_ranges_are_ew_number(first: int, last: int) -> None:
    state, _ = machine()
    with pytest.raises(OutOfRange) as caught:
        state.read_macros(first, last)
    assert caught.value.code == EW_NUMBER
    if first == last:
        with pytest.raises(OutOfRange):
            state.write_macro(first, 1.0)
    assert state.write_log == []
