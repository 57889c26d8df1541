from __future__ import annotations

import random
from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.collect.clock import MAX_READINGS, ClockTracker, ClockTransition, cnc_to_utc_seconds

T0 = 1_790_000_000.0  # gateway wall time at monotonic 0 (an arbitrary 2026 moment)


class FakeCnc:
    """A CNC whose clock runs `offset` seconds from the gateway, shown to the second in `zone`."""

    def __init__(self, offset: float, zone: str = "UTC") -> None:
        self.offset = offset
        self.zone = ZoneInfo(zone)

    def wall(self, gateway_wall: float) -> datetime:
        utc = datetime.fromtimestamp(int(gateway_wall + self.offset), UTC)
        return utc.astimezone(self.zone).replace(tzinfo=None)


def run(tracker: ClockTracker, cnc: FakeCnc, ticks: int, period: float = 0.25, start: float = 0.0,
        jitter: float = 0.0, seed: int = 1) -> float:
    rng = random.Random(seed)
    mono = start
    for _ in range(ticks):
        mono += period + rng.uniform(0, jitter)
        tracker.observe(cnc.wall(T0 + mono), mono, T0 + mono)
    return mono


def test_cnc_37_seconds_ahead_gives_cnc_time_within_50_ms() -> None:
    tracker = ClockTracker("UTC", max_skew_s=60)
    mono = run(tracker, FakeCnc(37.3), ticks=12, period=0.25, jitter=0.05)
    assert not tracker.use_gateway_time and tracker.reason is None
    stamp = tracker.source_time_ms(mono, T0 + mono)
    assert abs(stamp - (T0 + mono + 37.3) * 1000) < 50
    assert tracker.skew_s == pytest.approx(37.3, abs=0.05)
    assert tracker.uncertainty_s is not None and tracker.uncertainty_s < 0.2


def test_time_zone_is_applied() -> None:
    tracker = ClockTracker("America/Chicago", max_skew_s=60)
    mono = run(tracker, FakeCnc(5.0, "America/Chicago"), ticks=20, jitter=0.03)
    assert abs(tracker.source_time_ms(mono, T0 + mono) - (T0 + mono + 5.0) * 1000) < 60
    naive = datetime(2026, 7, 1, 12, 0, 0)
    assert cnc_to_utc_seconds(naive, ZoneInfo("America/Chicago")) == \
        datetime(2026, 7, 1, 17, 0, 0, tzinfo=UTC).timestamp()


def test_skew_beyond_limit_uses_gateway_time_then_recovers() -> None:
    cnc = FakeCnc(3600.0)  # a wrong time zone, say
    tracker = ClockTracker("UTC", max_skew_s=60)
    assert tracker.use_gateway_time and tracker.reason == "no CNC clock reading yet"
    mono = 0.25
    assert tracker.observe(cnc.wall(T0 + mono), mono, T0 + mono) is None  # was gateway, still gateway
    mono = run(tracker, cnc, ticks=8, start=mono)
    assert tracker.use_gateway_time
    assert tracker.reason is not None and "ahead of the gateway" in tracker.reason and "60" in tracker.reason
    assert tracker.source_time_ms(mono, T0 + mono) == round((T0 + mono) * 1000)

    cnc.offset = 2.0  # someone fixed the clock
    transitions = []
    for _ in range(8):
        mono += 0.25
        transitions.append(tracker.observe(cnc.wall(T0 + mono), mono, T0 + mono))
    assert ClockTransition.TO_CNC in transitions
    assert not tracker.use_gateway_time and tracker.reason is None
    assert tracker.restarts >= 1
    assert abs(tracker.source_time_ms(mono, T0 + mono) - (T0 + mono + 2.0) * 1000) < 260

    cnc.offset = -120.0
    mono += 0.25
    assert tracker.observe(cnc.wall(T0 + mono), mono, T0 + mono) is ClockTransition.TO_GATEWAY
    assert tracker.reason is not None and "behind" in tracker.reason


def test_gateway_wall_step_does_not_move_cnc_time() -> None:
    tracker = ClockTracker("UTC", max_skew_s=60)
    cnc = FakeCnc(10.0)
    mono = run(tracker, cnc, ticks=20, jitter=0.05)
    before = tracker.source_time_ms(mono, T0 + mono)
    # the gateway's NTP steps its wall clock 5 s; monotonic time and the CNC do not care
    assert tracker.source_time_ms(mono, T0 + mono + 5) == before


def test_round_trip_margin_keeps_noisy_readings_consistent() -> None:
    tracker = ClockTracker("UTC", max_skew_s=60)
    cnc = FakeCnc(0.4)
    rng = random.Random(7)
    mono = 0.0
    for _ in range(200):
        mono += 0.25 + rng.uniform(0, 0.02)
        sampled_at = mono + rng.uniform(-0.01, 0.01)  # the CNC read its clock inside the request
        tracker.observe(cnc.wall(T0 + sampled_at), mono, T0 + mono, half_rtt_s=0.01)
    assert tracker.restarts == 0
    assert abs(tracker.source_time_ms(mono, T0 + mono) - (T0 + mono + 0.4) * 1000) < 50


def test_reset_forgets() -> None:
    tracker = ClockTracker(ZoneInfo("UTC"), max_skew_s=60)
    run(tracker, FakeCnc(1.0), ticks=5)
    tracker.reset()
    assert tracker.offset_s is None and tracker.skew_s is None and tracker.use_gateway_time


def test_window_expires_old_readings() -> None:
    tracker = ClockTracker("UTC", max_skew_s=600, window_s=10)
    cnc = FakeCnc(0.0)
    mono = run(tracker, cnc, ticks=100, period=0.25, jitter=0.05)
    assert mono > 20
    cnc.offset = 0.5  # a slow drift that the old readings would contradict
    mono = run(tracker, cnc, ticks=100, start=mono, jitter=0.05)
    assert abs(tracker.source_time_ms(mono, T0 + mono) - (T0 + mono + 0.5) * 1000) < 60


def test_offset_of_a_naive_vs_aware_time() -> None:
    aware = datetime(2026, 1, 1, tzinfo=UTC) + timedelta(hours=1)
    assert cnc_to_utc_seconds(aware, ZoneInfo("Asia/Tokyo")) == aware.timestamp()


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(["Europe/Berlin", "America/Chicago", "Australia/Lord_Howe", "Asia/Kolkata", "UTC"]),
       st.datetimes(min_value=datetime(1990, 1, 1), max_value=datetime(2060, 1, 1)), st.sampled_from([0, 1]),
       st.sampled_from([0, 1]))
def test_a_naive_cnc_time_converts_as_the_zone_aware_time_would(zone: str, wall: datetime, fold: int,
                                                                   near_a_change: int) -> None:
    tz = ZoneInfo(zone)
    if near_a_change:  # the hours around a DST change: gaps (times that never happened) and folds (twice)
        wall = wall.replace(month=3 if wall.month < 7 else 10, day=25 + wall.day % 7, hour=wall.hour % 4)
    wall = wall.replace(fold=fold)
    assert cnc_to_utc_seconds(wall, tz) == wall.replace(tzinfo=tz).timestamp()


def test_one_reading_is_at_most_half_a_second_off() -> None:
    tracker = ClockTracker("UTC", max_skew_s=60)
    cnc = FakeCnc(37.9)  # T0 is a whole second, so the CNC is 0.9 s into its second at mono 0
    tracker.observe(cnc.wall(T0), 0.0, T0)
    assert tracker.uncertainty_s == pytest.approx(0.5)
    assert abs(tracker.source_time_ms(0.0, T0) - (T0 + 37.9) * 1000) <= 500


class WholeWindowTracker:
    """The tracker's rule stated plainly (every reading of the window kept and scanned): the reference
    the real tracker, which keeps only the readings that can still be an extreme, must agree with."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.readings: list[tuple[float, float, float]] = []  # (lower, upper, monotonic)
        self.restarts = 0

    def observe(self, cnc_wall: datetime, mono: float, half_rtt: float) -> None:
        base = cnc_to_utc_seconds(cnc_wall, ZoneInfo("UTC")) - mono
        margin = max(half_rtt, 0.0)
        self.readings.append((base - margin, base + 1.0 + margin, mono))
        self.readings = [r for r in self.readings[-MAX_READINGS:] if mono - r[2] <= self.window_s]
        if max(r[0] for r in self.readings) >= min(r[1] for r in self.readings):
            self.restarts += 1
            low, high, keep = float("-inf"), float("inf"), 0
            for lower, upper, _ in reversed(self.readings):
                low, high = max(low, lower), min(high, upper)
                if low >= high:
                    break
                keep += 1
            self.readings = self.readings[-keep:]

    @property
    def interval(self) -> tuple[float, float]:
        return max(r[0] for r in self.readings), min(r[1] for r in self.readings)


steps = st.tuples(st.floats(0.01, 3.0), st.sampled_from([0.0, 0.0, 0.0, 0.4, -2.0, 30.0, 3600.0]),
                  st.floats(0.0, 0.05))


@settings(max_examples=200, deadline=None)
@given(st.lists(steps, min_size=1, max_size=700), st.sampled_from([5.0, 60.0, 300.0]))
def test_kept_extremes_agree_with_scanning_the_whole_window(run_steps: list[tuple[float, float, float]],
                                                           window_s: float) -> None:
    tracker = ClockTracker("UTC", max_skew_s=60, window_s=window_s)
    reference = WholeWindowTracker(window_s)
    cnc = FakeCnc(12.3)
    mono = 0.0
    for advance, jump, half_rtt in run_steps:
        mono += advance
        cnc.offset += jump
        wall = cnc.wall(T0 + mono)
        tracker.observe(wall, mono, T0 + mono, half_rtt)
        reference.observe(wall, mono, half_rtt)
        low, high = reference.interval
        assert tracker.offset_s == (low + high) / 2
        assert tracker.uncertainty_s == (high - low) / 2
        assert tracker.restarts == reference.restarts


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.02, 0.3), st.floats(0.0, 0.05)), min_size=1, max_size=400),
       st.floats(-50.0, 50.0))
def test_observing_only_the_readings_that_narrow_gives_the_same_interval(
        run_steps: list[tuple[float, float]], offset: float) -> None:
    """What the poller does with the ~10 readings of each CNC second: skip those `narrows` rejects."""
    everything = ClockTracker("UTC", max_skew_s=60, window_s=1e9)
    selective = ClockTracker("UTC", max_skew_s=60, window_s=1e9)
    cnc = FakeCnc(offset)
    mono = 0.0
    observed = 0
    for advance, half_rtt in run_steps:
        mono += advance
        epoch = cnc_to_utc_seconds(cnc.wall(T0 + mono), ZoneInfo("UTC"))
        everything.observe_epoch(epoch, mono, T0 + mono, half_rtt)
        if selective.narrows(epoch, mono, half_rtt):
            selective.observe_epoch(epoch, mono, T0 + mono, half_rtt)
            observed += 1
        assert selective.offset_s == everything.offset_s
        assert selective.uncertainty_s == everything.uncertainty_s
    assert observed <= len(run_steps)


def test_a_steady_poll_observes_few_readings_once_the_offset_is_pinned() -> None:
    tracker = ClockTracker("UTC", max_skew_s=60)
    cnc = FakeCnc(7.37)
    mono, observed, ticks = 0.0, 0, 600  # a minute at 10 Hz, phase drifting against the CNC second
    for _ in range(ticks):
        mono += 0.1003
        epoch = cnc_to_utc_seconds(cnc.wall(T0 + mono), ZoneInfo("UTC"))
        if tracker.narrows(epoch, mono, 0.001):
            tracker.observe_epoch(epoch, mono, T0 + mono, 0.001)
            observed += 1
    assert observed < ticks / 5
    assert abs(tracker.source_time_ms(mono, T0 + mono) / 1000 - (T0 + mono + 7.37)) < 0.02


# -- CNC clock steps within the skew limit (issue 16, point 12) -------------------------------------------

def stamps_across_a_step(step: float, before: int = 40,
                         after: int = 400) -> tuple[ClockTracker, list[tuple[float, int]]]:
    """(monotonic, stamp) per tick, polled every 0.25 s, the CNC clock stepped by `step` after `before` ticks."""
    tracker = ClockTracker("UTC", max_skew_s=60)
    cnc = FakeCnc(0.0)
    rng = random.Random(3)
    out = []
    mono = 0.0
    for i in range(before + after):
        if i == before:
            cnc.offset += step
        mono += 0.25 + rng.uniform(0, 0.03)
        tracker.observe(cnc.wall(T0 + mono), mono, T0 + mono)
        out.append((mono, tracker.source_time_ms(mono, T0 + mono)))
    return tracker, out


def test_backward_step_never_stamps_back_and_meets_the_new_cnc_time() -> None:
    tracker, stamps = stamps_across_a_step(-30.0)
    values = [stamp for _, stamp in stamps]
    assert values == sorted(values), "a stamp earlier than one already given"
    assert tracker.steps == 1 and tracker.last_step_s == pytest.approx(-30.0, abs=1.0)
    assert tracker.skew_s == pytest.approx(-30.0, abs=0.6), "the offset itself is re-synced at once"
    # Stamps advance at half speed until they meet the CNC clock: 30 s absorbed in about 60 s.
    mono_at_step = stamps[40][0]
    met = next(m for m, stamp in stamps[40:] if abs(stamp - (T0 + m - 30.0) * 1000) < 600)
    assert 55 < met - mono_at_step < 66, met - mono_at_step
    last_mono, last = stamps[-1]
    assert abs(last - (T0 + last_mono - 30.0) * 1000) < 300, "CNC time again"


def test_forward_step_is_followed_at_once() -> None:
    tracker, stamps = stamps_across_a_step(+30.0, after=20)
    assert tracker.steps == 1 and tracker.last_step_s == pytest.approx(30.0, abs=1.0)
    mono, stamp = stamps[41]  # the tick after the step
    assert abs(stamp - (T0 + mono + 30.0) * 1000) < 600
    values = [s for _, s in stamps]
    assert values == sorted(values)


def test_drift_and_jitter_are_not_steps() -> None:
    tracker = ClockTracker("UTC", max_skew_s=600, window_s=10)
    cnc = FakeCnc(0.0)
    mono = run(tracker, cnc, ticks=100, period=0.25, jitter=0.05)
    cnc.offset = 0.5
    run(tracker, cnc, ticks=100, start=mono, jitter=0.05)
    assert tracker.restarts >= 1 and tracker.steps == 0
