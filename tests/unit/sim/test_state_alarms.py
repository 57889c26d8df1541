"""The simulated machine's alarms: raised and cleared by the cycle, the history ring."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

from edge.sim.state_alarms import ALARM_HISTORY_SIZE
from edge.sim.state_program import CycleSpec
from tests.unit.sim.helpers import T0, machine


def test_alarms_come_and_go_and_enter_the_history() -> None:
    cycle = CycleSpec(cut_seconds=10.0, idle_seconds=5.0, alarm_every=2, alarm_seconds=3.0)
    state, clock = machine(cycle=cycle, timezone="America/Chicago", clock_offset=90.0)
    seeded = len(state.alarm_history())
    clock.tick(15.0 + 10.6)  # second cycle's idle: alarm raised at 25.5 s
    alarms = state.active_alarms()
    assert len(alarms) == 1 and state.status().alarm == 1
    assert state.alarm_status() == 1 << alarms[0].type
    newest = state.alarm_events(1)[0]
    raised_at = T0 + 25.5
    expected_local = datetime.fromtimestamp(raised_at + 90.0, ZoneInfo("America/Chicago")).replace(
        tzinfo=None, microsecond=0)
    assert newest.local_time == expected_local
    assert newest.utc_time == datetime.fromtimestamp(raised_at, UTC)
    entry = state.alarm_history(1)[0]
    assert (entry.alm_no, entry.occurred) == (alarms[0].number, expected_local.replace(tzinfo=UTC))
    clock.tick(3.0)
    assert state.active_alarms() == [] and state.status().alarm == 0
    assert len(state.alarm_history()) == seeded + 1


def test_history_is_newest_first_and_depth_is_clamped() -> None:
    state, clock = machine()
    state.raise_alarm(1004, message="COOLANT LEVEL LOW")
    clock.tick(60)
    state.raise_alarm(2001, type=4, axis=2, message="LUBE")
    history = state.alarm_history(2)
    assert [e.alm_no for e in history] == [2001, 1004]
    assert history[0].occurred - history[1].occurred == timedelta(seconds=60)
    assert len(state.alarm_history(0)) == 1
    assert len(state.alarm_history(10_000)) == len(state.alarm_history(ALARM_HISTORY_SIZE))
    assert {a.number for a in state.active_alarms()} == {1004, 2001}
    state.clear_alarms(1004)
    assert [a.number for a in state.active_alarms()] == [2001]
    state.clear_alarms()
    assert state.active_alarms() == [] and state.alarm_status() == 0


def test_history_ring_keeps_250() -> None:
    state, clock = machine()
    for number in range(300):
        clock.tick(1)
        state.raise_alarm(3000 + number)
    history = state.alarm_history(ALARM_HISTORY_SIZE)
    assert len(history) == ALARM_HISTORY_SIZE
    assert history[0].alm_no == 3299 and history[-1].alm_no == 3050
