"""The simulated machine's clock (real time plus offset, in the CNC zone; setting it) and its timers."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from edge.focas.errors import (
    EW_DATA,
    CncError,
    OutOfRange,
)
from edge.sim.state_clock import clock_macro_error, clock_macro_value
from tests.unit.sim.helpers import T0, machine


def test_clock_is_real_time_plus_offset_in_the_cnc_zone() -> None:
    state, _ = machine(timezone="Europe/Berlin", clock_offset=-30.0)
    assert state.clock() == datetime(2025, 6, 15, 17, 6, 10)  # UTC+2 in June, 30 s slow
    assert state.clock_utc() == datetime(2025, 6, 15, 15, 6, 10, tzinfo=UTC)
    state.timezone = "Asia/Tokyo"
    state.clock_offset = 0
    assert state.clock() == datetime(2025, 6, 16, 0, 6, 40)


def test_setting_the_clock_moves_the_offset() -> None:
    state, clock = machine(timezone="Europe/Berlin")
    state.set_clock(datetime(2025, 6, 15, 17, 10, 0))
    assert state.clock_offset == pytest.approx(200.0)
    clock.tick(5)
    assert state.clock() == datetime(2025, 6, 15, 17, 10, 5)
    state.set_time_of_day(8, 0, 0)
    assert state.clock() == datetime(2025, 6, 15, 8, 0, 0)
    with pytest.raises(CncError) as bad:
        state.set_time_of_day(25, 0, 0)
    assert bad.value.code == EW_DATA


def test_timers() -> None:
    state, clock = machine()
    before = state.timer(0)
    clock.tick(120)
    after = state.timer(0)
    assert after.minutes - before.minutes == 2
    assert state.timer(2).minutes >= 0 and 0 <= state.timer(3).msec < 60_000
    with pytest.raises(OutOfRange):
        state.timer(9)


def test_the_clock_macro_reads_as_the_cnc_clock_when_it_answers() -> None:
    """The hook the timestamp tests and the fleet benchmark compare stamps with (seconds mod 1000, ms)."""
    state, clock = machine(clock_offset=7.25)
    state.write_macro(500, 1.0)
    state.write_macro(501, 3.0)
    state.write_macro(502, None)
    assert state.read_macros(500, 502)[0] == 1.0  # no hook: an ordinary macro
    state.clock_macro = 500
    clock.tick(0.4567)
    value = state.read_macros(500, 502)[0]
    assert value == clock_macro_value(T0 + 0.4567 + 7.25) == round((T0 + 7.7067) % 1000, 3)
    assert state.read_macros(501, 502) == [3.0, None]  # the others are what they hold
    assert clock_macro_error(T0 + 7.7067 + 0.012, value) == pytest.approx(0.012, abs=1e-3)
    assert clock_macro_error(T0 + 7.7067 - 0.012, value) == pytest.approx(-0.012, abs=1e-3)
    assert clock_macro_error(999.995, 0.005) == pytest.approx(-0.01)  # across the wrap of the modulo
