"""The simulated machine's clock (real time plus offset, in the CNC zone; setting it) and its timers."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from edge.focas.errors import (
    EW_DATA,
    CncError,
    OutOfRange,
)
from tests.unit.sim.helpers import machine


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
