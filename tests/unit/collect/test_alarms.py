from __future__ import annotations

import json
import os
from datetime import UTC, datetime, timedelta
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from edge.collect.alarms import (
    ActiveAlarmProjection,
    AlarmHistoryDedup,
    Watermark,
    WatermarkStore,
    history_event,
)
from edge.focas.model import ActiveAlarm, AlarmHistoryEntry
from edge.statefile import write_atomically

BASE = datetime(2026, 3, 1, 8, 0, 0, tzinfo=UTC)


def entry(seconds: int, number: int, alm_type: int = 1, axis: int = 0) -> AlarmHistoryEntry:
    return AlarmHistoryEntry(BASE + timedelta(seconds=seconds), axis, alm_type, number, f"ALARM {number}")


def ring(*entries: AlarmHistoryEntry) -> list[AlarmHistoryEntry]:
    """As the CNC answers: newest first."""
    return sorted(entries, key=lambda e: e.occurred, reverse=True)


# ---- active alarms ----------------------------------------------------------------------------------


def test_raise_and_clear_by_type_number_axis() -> None:
    projection = ActiveAlarmProjection()
    a = ActiveAlarm(1001, 2, 0, "OVERTRAVEL")
    b = ActiveAlarm(1001, 2, 1, "OVERTRAVEL")  # same number, other axis: another alarm
    events = projection.update([a, b], 1000)
    assert [(e.kind, e.alarm) for e in events] == [("raised", a), ("raised", b)]
    assert projection.update([a, b], 1250) == []
    renamed = ActiveAlarm(1001, 2, 0, "OVERTRAVEL +X")
    assert projection.update([renamed, b], 1500) == []  # a new text is not a new alarm
    events = projection.update([b], 1750)
    assert [(e.kind, e.alarm.axis, e.timestamp_ms) for e in events] == [("cleared", 0, 1750)]
    assert events[0].as_dict()["event"] == "cleared"
    assert projection.active == [b]


def test_state_survives_a_reconnect_unless_reset() -> None:
    projection = ActiveAlarmProjection()
    a = ActiveAlarm(500, 4, 0, "OT")
    projection.update([a], 1)
    assert projection.update([a], 2) == []
    projection.reset()
    assert [e.kind for e in projection.update([a], 3)] == ["raised"]


def test_alarm_status_change_detection() -> None:
    projection = ActiveAlarmProjection()
    assert projection.status_changed(0)
    assert not projection.status_changed(0)
    assert projection.status_changed(4)
    projection.reset()
    assert projection.status_changed(4)


# ---- history ----------------------------------------------------------------------------------------


def test_first_read_publishes_the_ring_oldest_first() -> None:
    dedup = AlarmHistoryDedup()
    entries = ring(entry(0, 1), entry(10, 2), entry(20, 3))
    fresh = dedup.new_entries(entries)
    assert [e.alm_no for e in fresh] == [1, 2, 3]


def test_nothing_republished_after_restart_and_new_alarm_once(tmp_path: Path) -> None:
    first = AlarmHistoryDedup(WatermarkStore(tmp_path, "mill-1"))
    entries = ring(entry(0, 1), entry(10, 2), entry(20, 3))
    first.commit(first.new_entries(entries))

    restarted = AlarmHistoryDedup(WatermarkStore(tmp_path, "mill-1"))  # a new process
    assert restarted.new_entries(entries) == []
    newer = ring(*entries, entry(30, 4))
    fresh = restarted.new_entries(newer)
    assert [e.alm_no for e in fresh] == [4]
    restarted.commit(fresh)
    assert restarted.new_entries(newer) == []
    assert AlarmHistoryDedup(WatermarkStore(tmp_path, "mill-1")).new_entries(newer) == []
    # another machine has its own watermark
    assert len(AlarmHistoryDedup(WatermarkStore(tmp_path, "mill-2")).new_entries(newer)) == 4


def test_equal_timestamps_are_told_apart_by_number_and_type() -> None:
    dedup = AlarmHistoryDedup()
    dedup.commit(dedup.new_entries(ring(entry(5, 100), entry(5, 101))))
    later = ring(entry(5, 100), entry(5, 101), entry(5, 102), entry(5, 100, alm_type=2))
    fresh = dedup.new_entries(later)
    assert sorted((e.alm_no, e.alm_type) for e in fresh) == [(100, 2), (102, 1)]
    dedup.commit(fresh)
    assert dedup.new_entries(later) == []


def test_identical_keys_in_one_second_are_counted() -> None:
    dedup = AlarmHistoryDedup()
    dedup.commit(dedup.new_entries([entry(5, 100)]))
    fresh = dedup.new_entries([entry(5, 100), entry(5, 100)])  # the same alarm twice in that second
    assert len(fresh) == 1
    dedup.commit(fresh)
    assert dedup.new_entries([entry(5, 100), entry(5, 100)]) == []


def test_uncommitted_entries_come_again() -> None:
    dedup = AlarmHistoryDedup()
    entries = ring(entry(0, 1))
    assert dedup.new_entries(entries) and dedup.new_entries(entries)  # not published yet: at-least-once


def test_ring_rolling_over_does_not_resurrect_old_entries() -> None:
    dedup = AlarmHistoryDedup()
    dedup.commit(dedup.new_entries(ring(*(entry(i, i) for i in range(10)))))
    rolled = ring(*(entry(i, i) for i in range(5, 12)))  # oldest fell out, two new at the top
    assert [e.alm_no for e in dedup.new_entries(rolled)] == [10, 11]


def test_watermark_file_is_json_and_corruption_starts_fresh(tmp_path: Path) -> None:
    store = WatermarkStore(tmp_path, "odd id/with slash")
    dedup = AlarmHistoryDedup(store)
    dedup.commit(dedup.new_entries([entry(0, 1)]))
    assert store.path.parent == tmp_path / "alarm-history"
    data = json.loads(store.path.read_text())
    assert data["version"] == 1 and data["time_ms"] == int(BASE.timestamp() * 1000)
    store.path.write_text("{not json")
    assert store.load() == Watermark()
    store.path.write_text('{"version": 1, "time_ms": "soon"}')
    assert store.load() == Watermark()


def test_atomic_write_leaves_no_temp_files(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "state.json"
    write_atomically(target, b"one")
    write_atomically(target, b"two")
    assert target.read_bytes() == b"two"
    assert os.listdir(target.parent) == ["state.json"]


def test_history_event_carries_cnc_occurrence_time() -> None:
    event = history_event(entry(3, 1010))
    assert event["occurred"] == "2026-03-01T08:00:03Z"
    assert event["occurred_ms"] == int((BASE.timestamp() + 3) * 1000)
    assert event["number"] == 1010


@given(st.lists(st.tuples(st.integers(0, 20), st.integers(1, 4), st.integers(1, 2)), max_size=30),
       st.integers(0, 30))
def test_every_entry_published_exactly_once(raw: list[tuple[int, int, int]], split: int) -> None:
    """However the ring grows between reads, each entry is published once overall."""
    entries = [entry(t, n, k) for t, n, k in sorted(raw)]
    dedup = AlarmHistoryDedup()
    published: list[AlarmHistoryEntry] = []
    for visible in (entries[:split], entries):
        fresh = dedup.new_entries(ring(*visible))
        published += fresh
        dedup.commit(fresh)
    key = lambda e: (e.occurred, e.alm_no, e.alm_type)  # noqa: E731
    assert sorted(published, key=key) == sorted(entries, key=key)
