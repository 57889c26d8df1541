"""Utilisation counters with a clock the test controls: midnight rollover, DST days, restarts, the state file."""

from __future__ import annotations

import json
import logging
from datetime import date, datetime
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest

from edge.collect.minute_timers import MinuteTimers
from edge.collect.plant_state import PlantState
from edge.collect.utilisation import UtilisationCounter, UtilisationStore
from edge.focas.model import StatInfo
from tests.helpers import async_wait_for

BERLIN = ZoneInfo("Europe/Berlin")
CUTTING = StatInfo(1, 3, 1, 0, 0, 0, 0)
HELD = StatInfo(1, 2, 0, 0, 0, 0, 0)
IN_ALARM = StatInfo(1, 0, 0, 0, 0, 1, 0)


def ms(text: str, zone: ZoneInfo = BERLIN) -> int:
    """Epoch ms of a local wall time `YYYY-MM-DD HH:MM:SS` in `zone`."""
    return round(datetime.fromisoformat(text).replace(tzinfo=zone).timestamp() * 1000)


def values(samples: list) -> dict[str, object]:  # type: ignore[type-arg]
    return {s.name: s.value for s in samples}


def test_counting_between_changes_of_state() -> None:
    counter = UtilisationCounter(BERLIN, "READY", ms("2026-06-10 08:00:00"))
    assert counter.switch("ACTIVE", ms("2026-06-10 08:00:30")) == []
    counter.switch("FEED_HOLD", ms("2026-06-10 08:10:30"))
    counter.advance(ms("2026-06-10 08:11:00"))
    assert counter.seconds["READY"] == 30 and counter.seconds["ACTIVE"] == 600 and counter.seconds["FEED_HOLD"] == 30
    assert counter.day == date(2026, 6, 10)


def test_a_time_before_what_is_counted_counts_nothing() -> None:
    counter = UtilisationCounter(BERLIN, "ACTIVE", ms("2026-06-10 08:00:00"))
    counter.advance(ms("2026-06-10 08:01:00"))
    counter.switch("READY", ms("2026-06-10 08:00:50"))  # a CNC stamp 10 s behind the minute publish
    counter.advance(ms("2026-06-10 08:02:00"))
    assert counter.seconds["ACTIVE"] == 60 and counter.seconds["READY"] == 60


def test_rollover_at_local_midnight_splits_the_interval_and_hands_back_the_finished_day() -> None:
    counter = UtilisationCounter(BERLIN, "READY", ms("2026-06-10 23:59:00"))
    counter.switch("ACTIVE", ms("2026-06-10 23:59:30"))
    ended = counter.advance(ms("2026-06-11 00:00:45"))
    (day,) = ended
    assert day.day == date(2026, 6, 10) and day.at_ms == ms("2026-06-11 00:00:00") - 1
    assert day.seconds["READY"] == 30 and day.seconds["ACTIVE"] == 30
    assert values(day.samples())["Utilisation/Day"] == "2026-06-10"
    assert counter.day == date(2026, 6, 11) and counter.seconds["ACTIVE"] == 45 and counter.seconds["READY"] == 0
    assert values(counter.totals().samples())["Utilisation/Day"] == "2026-06-11"


def test_midnight_is_the_machines_zone_not_utc() -> None:
    counter = UtilisationCounter(BERLIN, "ACTIVE", ms("2026-06-10 23:00:00"))
    assert counter.advance(ms("2026-06-10 23:59:59")) == []  # 21:59 UTC: still the 10th in Berlin
    assert [d.day for d in counter.advance(ms("2026-06-11 00:00:00"))] == [date(2026, 6, 10)]


def test_a_day_with_a_dst_change_has_its_own_length() -> None:
    counter = UtilisationCounter(BERLIN, "ACTIVE", ms("2026-03-29 00:00:00"))
    (spring,) = counter.advance(ms("2026-03-30 00:00:00"))
    assert sum(spring.seconds.values()) == 23 * 3600
    (autumn,) = UtilisationCounter(BERLIN, "ACTIVE", ms("2026-10-25 00:00:00")).advance(ms("2026-10-26 00:00:00"))
    assert sum(autumn.seconds.values()) == 25 * 3600


def test_a_gap_over_several_midnights_ends_each_day() -> None:
    counter = UtilisationCounter(BERLIN, "UNKNOWN", ms("2026-06-10 12:00:00"))
    ended = counter.advance(ms("2026-06-13 06:00:00"))
    assert [d.day for d in ended] == [date(2026, 6, 10), date(2026, 6, 11), date(2026, 6, 12)]
    assert [d.seconds["UNKNOWN"] for d in ended] == [12 * 3600, 24 * 3600, 24 * 3600]
    assert counter.seconds["UNKNOWN"] == 6 * 3600


def test_first_start_counts_midnight_until_now_as_unknown(tmp_path: Path) -> None:
    state = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:00:00"))
    assert state.counter.state == "OFFLINE" and state.counter.seconds["UNKNOWN"] == 6 * 3600


def test_restart_keeps_the_day_and_counts_the_gap_as_unknown(tmp_path: Path) -> None:
    """Counters survive a stop and start; the 5 minutes the gateway was down are UNKNOWN, not ACTIVE."""
    first = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:00:00"))
    first.status(CUTTING, ms("2026-06-10 06:00:10"))
    first.close(ms("2026-06-10 06:10:10"))  # still cutting when the daemon stops
    second = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:15:10"))
    seconds = second.counter.seconds
    assert seconds["ACTIVE"] == 600 and seconds["OFFLINE"] == 10
    assert seconds["UNKNOWN"] == 6 * 3600 + 300
    assert second.counter.state == "OFFLINE" and second.counter.day == date(2026, 6, 10)
    second.status(HELD, ms("2026-06-10 06:15:12"))
    second.close(ms("2026-06-10 06:16:12"))
    third = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:16:12"))
    assert third.counter.seconds["FEED_HOLD"] == 60 and third.counter.seconds["ACTIVE"] == 600


def test_restart_after_midnight_starts_the_new_day_with_the_gap_unknown(tmp_path: Path) -> None:
    first = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 23:00:00"))
    first.status(CUTTING, ms("2026-06-10 23:00:00"))
    first.close(ms("2026-06-10 23:50:00"))
    second = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-11 00:10:00"))
    assert second.counter.day == date(2026, 6, 11)
    assert second.counter.seconds["UNKNOWN"] == 600 and second.counter.seconds["ACTIVE"] == 0


def test_publishes_on_change_of_state_only(tmp_path: Path) -> None:
    state = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:00:00"))
    moved = values(state.status(CUTTING, ms("2026-06-10 06:00:05")))
    assert moved == {"Utilisation/OFFLINE": 5.0}  # only the counter of the state that ended moved
    assert state.status(StatInfo(1, 3, 2, 0, 0, 0, 0), ms("2026-06-10 06:00:06")) == []  # dwell: still ACTIVE
    assert values(state.status(IN_ALARM, ms("2026-06-10 06:01:05"))) == {"Utilisation/ACTIVE": 60.0}
    offline = values(state.offline(ms("2026-06-10 06:02:05")))
    assert offline["Status/Availability"] == "UNAVAILABLE" and offline["Utilisation/ALARM"] == 60.0
    birth = values(state.birth_samples(ms("2026-06-10 06:03:05")))
    assert birth["Status/Availability"] == "AVAILABLE" and birth["Utilisation/OFFLINE"] == 65.0


def test_the_minute_publish_counts_the_current_state_and_wakes_at_midnight(tmp_path: Path) -> None:
    state = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 23:58:00"))
    state.status(CUTTING, ms("2026-06-10 23:58:00"))
    assert values(state.minute(ms("2026-06-10 23:59:00")))["Utilisation/ACTIVE"] == 60.0
    wall = ms("2026-06-10 23:59:59") / 1000
    assert state.next_delay_s(wall, ms("2026-06-10 23:59:59")) == pytest.approx(1.0)  # midnight before the minute
    published = state.minute(ms("2026-06-11 00:00:00"))
    days = [s.value for s in published if s.name == "Utilisation/Day"]
    assert days == ["2026-06-10", "2026-06-11"]  # the finished day's totals, then the new day's
    assert [s.value for s in published if s.name == "Utilisation/ACTIVE"] == [120.0, 0.0]
    assert 0.05 <= state.next_delay_s(wall + 1, ms("2026-06-11 00:00:00")) <= 60


def test_an_unreadable_file_is_named_and_the_day_starts_again(tmp_path: Path,
                                                             caplog: pytest.LogCaptureFixture) -> None:
    store = UtilisationStore(tmp_path, "m/1")
    store.path.parent.mkdir(parents=True)
    store.path.write_text('{"format": 1, "day": "yesterday"}')
    with caplog.at_level(logging.WARNING):
        state = PlantState("m/1", BERLIN, tmp_path, now_ms=ms("2026-06-10 01:00:00"))
    assert "utilisation file unreadable" in caplog.text and str(store.path) in caplog.text
    assert state.counter.seconds["UNKNOWN"] == 3600


def test_a_late_save_does_not_overwrite_a_newer_one(tmp_path: Path) -> None:
    store = UtilisationStore(tmp_path, "m1")
    store.save(2, {"format": 1, "n": "newer"})
    store.save(1, {"format": 1, "n": "older"})
    assert json.loads(store.path.read_text())["n"] == "newer"


async def test_the_minute_task_publishes_every_minute_and_saves_every_fifth(tmp_path: Path) -> None:
    state = PlantState("m1", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:00:00"))
    clock = [ms("2026-06-10 06:00:00")]

    def now_ms() -> int:  # asked twice a round: a minute passes per round
        clock[0] += 30_000
        return clock[0]

    saved_before: list[bool] = []  # at each publish: was the file already written?

    async def publish(samples: object) -> None:
        saved_before.append(state.store.path.exists())

    minutes = MinuteTimers.for_loop().start(state, now_ms, publish, wall=lambda: state._phase_s + 59.99)
    try:
        await async_wait_for(lambda: len(saved_before) >= 6, timeout=10, message="six minute publishes")
    finally:
        minutes.cancel()
    assert saved_before[:6] == [False] * 5 + [True]
    assert json.loads(state.store.path.read_text())["seconds"]["OFFLINE"] == 5 * 60


async def test_machines_share_the_minute_timer_and_a_cancelled_one_publishes_no_more(tmp_path: Path) -> None:
    states = [PlantState(f"m{n}", BERLIN, tmp_path, now_ms=ms("2026-06-10 06:00:00")) for n in range(3)]
    clock = [ms("2026-06-10 06:00:00")]

    def now_ms() -> int:
        clock[0] += 30_000
        return clock[0]

    published: dict[str, int] = {state.device_id: 0 for state in states}

    def publisher(device_id: str):  # type: ignore[no-untyped-def]
        async def publish(samples: object) -> None:
            published[device_id] += 1
        return publish

    timers = MinuteTimers.for_loop()
    assert MinuteTimers.for_loop() is timers  # one per event loop
    rounds = [timers.start(state, now_ms, publisher(state.device_id), wall=lambda s=state: s._phase_s + 59.99)
              for state in states]
    try:
        await async_wait_for(lambda: min(published.values()) >= 2, timeout=10, message="every machine's minutes")
        rounds[1].cancel()
        stopped_at = published["m1"]
        others = published["m0"]
        await async_wait_for(lambda: published["m0"] >= others + 3, timeout=10, message="the others go on")
        assert published["m1"] == stopped_at
        assert len(timers._heap) <= 3  # a machine waiting for its minute is one heap entry, no task
    finally:
        for minutes in rounds:
            minutes.cancel()
