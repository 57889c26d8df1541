"""The plant page's recorder: bands from the status samples, the day strip, the hour, sparklines, alarms."""

from __future__ import annotations

import json

import pytest

from edge.samples import MetricType, Quality, Sample
from edge.service.trends import (
    ALARMS_KEPT,
    DAY_MINUTES,
    HOUR_TRANSITIONS,
    SPARK_POINTS,
    Band,
    TrendRecorder,
    band_of,
)

T0 = 1_764_000_000.0  # a minute boundary (divisible by 60)


class Clock:
    def __init__(self, now: float = T0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def relative(runs: list[tuple[float, float, Band]]) -> list[tuple[float, float, Band]]:
    """Bands with their times relative to T0, to compare with a literal."""
    return [(a - T0, b - T0, band) for a, b, band in runs]


def s(name: str, value: object, kind: MetricType = MetricType.STRING) -> Sample:
    return Sample(name, value, kind, 0)


@pytest.mark.parametrize(("inputs", "band"), [
    ({"Status/Execution": "ACTIVE"}, Band.RUNNING),
    ({"Status/Execution": "FEED_HOLD"}, Band.FEED_HOLD),
    ({"Status/Execution": "INTERRUPTED"}, Band.FEED_HOLD),
    ({"Status/Execution": "READY"}, Band.IDLE),
    ({"Status/Execution": "PROGRAM_STOPPED"}, Band.IDLE),
    ({"Status/Execution": "UNAVAILABLE", "Status/Run": "START"}, Band.UNKNOWN),  # a run code nobody knows
    ({"Status/Execution": "ACTIVE", "Status/Run": "RESET"}, Band.RUNNING),  # the derived state wins
    ({"Status/Run": "START"}, Band.RUNNING),
    ({"Status/Run": "HOLD"}, Band.FEED_HOLD),
    ({"Status/Run": "RESET"}, Band.IDLE),
    ({"Status/Run": "START", "Status/Alarm": "BAT"}, Band.RUNNING),  # a warning, still cutting
    ({"Status/Run": "START", "Status/Alarm": "ALM"}, Band.ALARM),
    ({"Status/Run": "RESET", "Status/Alarm": "ALM", "Status/Emergency": True}, Band.EMERGENCY),
    ({"Status/Execution": "ACTIVE", "Status/Availability": "UNAVAILABLE", "Status/Emergency": True}, Band.OFFLINE),
    ({"Status/Run": None}, Band.UNKNOWN),  # a refused read
    ({}, Band.UNKNOWN),
])
def test_band_of_the_status_values(inputs: dict[str, object], band: Band) -> None:
    assert band_of(inputs) is band


async def test_bands_follow_the_samples_and_an_offline() -> None:
    clock = Clock()
    rec = TrendRecorder(clock)
    await rec.device_online("m1", [], [s("Status/Run", "START"), s("Status/Alarm", "")])
    clock.now += 40
    await rec.device_data("m1", [s("Status/Run", "HOLD")])
    clock.now += 20
    await rec.device_data("m1", [s("Status/Alarm", "ALM")])
    clock.now += 30
    await rec.device_offline("m1")
    clock.now += 10
    trend = rec.machine("m1")
    assert trend is not None and trend.band is Band.OFFLINE and trend.since == T0 + 90
    runs = trend.hour.bands(T0 - 60, clock.now)
    assert relative(runs) == [
        (-60, 0, Band.UNKNOWN), (0, 40, Band.RUNNING), (40, 60, Band.FEED_HOLD), (60, 90, Band.ALARM),
        (90, 100, Band.OFFLINE)]
    await rec.device_online("m1", [], [s("Status/Run", "RESET"), s("Status/Alarm", "")])
    assert trend.band is Band.IDLE  # the birth clears the offline


async def test_samples_that_do_not_change_the_band_add_no_transition() -> None:
    clock = Clock()
    rec = TrendRecorder(clock)
    for i in range(50):
        clock.now += 1
        await rec.device_data("m1", [s("Status/Run", "START"), s("Status/Motion", "MTN" if i % 2 else "")])
    trend = rec.machine("m1")
    assert trend is not None and len(trend.hour.codes) == 1 and trend.since == T0 + 1


async def test_the_day_strip_keeps_the_dominant_band_of_each_minute_and_unknown_before_the_first_sample() -> None:
    clock = Clock(T0 + 10)
    rec = TrendRecorder(clock)
    await rec.device_data("m1", [s("Status/Run", "START")])  # 10..50 running
    clock.now = T0 + 50
    await rec.device_data("m1", [s("Status/Run", "RESET")])  # 50 .. 3 min idle
    clock.now = T0 + 180
    await rec.device_data("m1", [s("Status/Run", "HOLD")])
    clock.now = T0 + 200
    trend = rec.machine("m1")
    assert trend is not None
    runs = trend.day.bands(T0 - 120, clock.now)
    assert relative(runs) == [
        (-120, 0, Band.UNKNOWN), (0, 60, Band.RUNNING), (60, 180, Band.IDLE), (180, 200, Band.FEED_HOLD)]
    assert trend.day.seconds_in(Band.IDLE, T0, clock.now) == 120


async def test_the_day_strip_holds_24_hours_and_a_long_quiet_spell_keeps_its_band() -> None:
    clock = Clock()
    rec = TrendRecorder(clock)
    await rec.device_data("m1", [s("Status/Run", "START")])
    clock.now += 30 * 3600  # no sample for 30 h: values come by exception, so it still runs
    trend = rec.machine("m1")
    assert trend is not None
    runs = trend.day.bands(clock.now - 24 * 3600, clock.now)
    assert runs == [(clock.now - 24 * 3600, clock.now, Band.RUNNING)]
    assert len(trend.day.slots) == DAY_MINUTES + 1


async def test_the_hour_forgets_older_transitions_and_is_capped() -> None:
    clock = Clock()
    rec = TrendRecorder(clock)
    for i in range(HOUR_TRANSITIONS * 2):
        clock.now += 1
        await rec.device_data("m1", [s("Status/Run", "START" if i % 2 else "RESET")])
    trend = rec.machine("m1")
    assert trend is not None and len(trend.hour.starts) == len(trend.hour.codes) == HOUR_TRANSITIONS
    clock.now += 2 * 3600
    await rec.device_data("m1", [s("Status/Run", "HOLD")])
    assert len(trend.hour.starts) == 2  # the band that still reaches into the hour, and the new one
    runs = trend.hour.bands(clock.now - 3600, clock.now + 5)
    assert [band for _, _, band in runs] == [Band.RUNNING if (HOUR_TRANSITIONS * 2 - 1) % 2 else Band.IDLE,
                                             Band.FEED_HOLD]


async def test_sparkline_means_are_weighted_by_time_held_peaks_kept_and_offline_breaks_the_line() -> None:
    clock = Clock()
    rec = TrendRecorder(clock)
    load = "Spindle/1/Load"
    await rec.device_data("m1", [s(load, 10.0, MetricType.DOUBLE)])  # 0..5 s
    clock.now += 5
    await rec.device_data("m1", [s(load, 40.0, MetricType.DOUBLE)])  # 5..10 s
    clock.now += 5
    await rec.device_data("m1", [s(load, 20.0, MetricType.DOUBLE)])  # 10 s on: step 0 = (50 + 200 + 400) / 30
    clock.now = T0 + 95  # steps 1 and 2 held 20, step 3 now
    await rec.device_offline("m1")
    clock.now = T0 + 125  # step 4: offline
    trend = rec.machine("m1")
    assert trend is not None
    means, peaks = trend.sparks[load].series(clock.now)
    assert len(means) == len(peaks) == SPARK_POINTS
    assert [None if m is None else round(m, 3) for m in means[-5:]] == [21.667, 20.0, 20.0, 20.0, None]
    assert peaks[-5:] == [40.0, 20.0, 20.0, 20.0, None]
    assert all(p is None for p in means[:-5] + peaks[:-5])
    await rec.device_data("m1", [Sample(load, None, MetricType.DOUBLE, 0, Quality.BAD)])
    assert trend.sparks[load].points(clock.now)[-1] is None
    await rec.device_data("m1", [s(load, 50.0, MetricType.DOUBLE)])
    clock.now = T0 + 10 * 3600  # ten quiet hours: the whole hour held 50
    assert set(trend.sparks[load].series(clock.now)[0]) == {50.0}


async def test_alarm_events_are_kept_capped_and_bad_ones_ignored() -> None:
    rec = TrendRecorder(Clock())
    for number in range(ALARMS_KEPT + 5):
        payload = {"event": "raised", "type": 2, "number": number, "axis": 0, "message": "OVERHEAT",
                   "timestamp_ms": 1_000 * number}
        await rec.device_events("m1", [s("Alarm/Event", json.dumps(payload))])
    await rec.device_events("m1", [s("Alarm/Event", "not json"), s("Alarm/Event", json.dumps({"event": "x"}))])
    trend = rec.machine("m1")
    assert trend is not None and len(trend.alarms) == ALARMS_KEPT
    assert trend.alarms[-1].number == ALARMS_KEPT + 4 and trend.alarms[-1].at == ALARMS_KEPT + 4
    assert trend.alarms[-1].message == "OVERHEAT" and trend.alarms[-1].event == "raised"


async def test_published_utilisation_is_kept_as_sent() -> None:
    rec = TrendRecorder(Clock())
    await rec.device_data("m1", [s("Utilisation/ACTIVE", 3600.0, MetricType.DOUBLE),
                                 s("Utilisation/Day", "2026-11-25")])
    trend = rec.machine("m1")
    assert trend is not None and trend.utilisation == {"ACTIVE": 3600.0, "Day": "2026-11-25"}
    rec.forget("m1")
    assert rec.machine("m1") is None
