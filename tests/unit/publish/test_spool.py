"""The disk spool: order, bounds and drop policy, durability across kill -9, and the outbox."""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.publish.forwarding import ForwardingPolicy, HeldBatch, Outbox
from edge.publish.spool import DiskSpool, open_spool
from edge.publish.spool_rows import decode_samples, encode_samples
from edge.samples import MetricType, Quality, Sample


def sample(i: int, name: str = "Macro/500", value: object = None) -> Sample:
    return Sample(name, float(i) if value is None else value, MetricType.DOUBLE, 1_700_000_000_000 + i)


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_rows_come_back_oldest_first_per_format_and_leave_on_ack(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite")
    for i in range(5):
        spool.hold("sparkplug", "m1", "data", [sample(i)])
        spool.hold("json", "m1", "data", [sample(i)])
    spool.hold("sparkplug", "m2", "events", [sample(9, "Alarm/Event", "x")])
    first = spool.oldest("sparkplug", 3)
    assert [e.samples[0].value for e in first] == [0.0, 1.0, 2.0]
    assert [e.id for e in first] == sorted(e.id for e in first)
    assert spool.pending("sparkplug") == 6 and spool.pending("json") == 5
    spool.ack([e.id for e in first])
    rest = spool.oldest("sparkplug", 10)
    assert [e.samples[0].value for e in rest] == [3.0, 4.0, "x"]
    assert rest[-1].kind == "events" and rest[-1].device_id == "m2"
    assert [e.device_id for e in spool.oldest("sparkplug", 10, devices={"m2"})] == ["m2"]
    assert spool.oldest("sparkplug", 10, devices=set()) == []
    spool.close()


def test_rows_survive_reopen_and_ids_keep_growing(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    spool = DiskSpool(path)
    spool.hold("json", "m1", "data", [sample(1)])
    spool.ack([spool.oldest("json", 1)[0].id])
    spool.hold("json", "m1", "data", [sample(2)])
    last_id = spool.oldest("json", 1)[0].id
    spool.close()
    again = DiskSpool(path)
    assert again.pending() == 1 and again.bytes > 0
    again.hold("json", "m1", "data", [sample(3)])
    ids = [e.id for e in again.oldest("json", 10)]
    assert ids[0] == last_id and ids[1] > last_id  # AUTOINCREMENT: a replayed id is never reused
    again.close()


def test_size_bound_drops_oldest_data_before_any_event(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite", max_bytes=4000)
    spool.hold("sparkplug", "m1", "events", [sample(0, "Alarm/Event", "raised")])
    for i in range(1, 200):
        spool.hold("sparkplug", "m1", "data", [sample(i, value="v" * 40)])
    assert spool.bytes <= 4000
    assert spool.dropped > 0
    left = spool.oldest("sparkplug", 1000)
    assert left[0].kind == "events"  # the alarm event outlived older data
    values = [e.samples[0].timestamp_ms for e in left[1:]]
    assert values == sorted(values) and values[-1] == 1_700_000_000_000 + 199  # the newest data kept
    assert spool.dropped + len(left) == 200
    spool.close()


def test_only_events_left_then_oldest_event_goes(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite", max_bytes=1000)
    for i in range(100):
        spool.hold("json", "m1", "events", [sample(i, "Alarm/Event", "e" * 30)])
    left = spool.oldest("json", 1000)
    assert left and spool.bytes <= 1000
    assert left[-1].samples[0].timestamp_ms == 1_700_000_000_000 + 99
    assert spool.dropped == 100 - len(left)
    spool.close()


def test_age_bound_drops_old_rows_and_counts_them(tmp_path: Path) -> None:
    clock = Clock()
    spool = DiskSpool(tmp_path / "s.sqlite", max_age_s=60, clock=clock)
    spool.hold("sparkplug", "m1", "data", [sample(1), sample(2)])
    clock.now += 30
    spool.hold("sparkplug", "m1", "data", [sample(3)])
    clock.now += 40  # the first row is 70 s old now
    assert [s.value for e in spool.oldest("sparkplug", 10) for s in e.samples] == [3.0]
    assert spool.dropped == 2
    spool.close()


def test_unreadable_row_is_dropped_not_blocking(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite")
    spool.hold("json", "m1", "data", [sample(1)])
    spool.hold("json", "m1", "data", [sample(2)])
    first = spool.oldest("json", 1)[0].id
    db = spool._conn()
    db.execute("UPDATE spool SET body = ? WHERE id = ?", (b"\xff not json", first))
    assert [s.value for e in spool.oldest("json", 10) for s in e.samples] == [2.0]
    assert spool.dropped == 1
    spool.close()


def test_bad_bounds_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="max_bytes"):
        DiskSpool(tmp_path / "s.sqlite", max_bytes=0)


CHILD = """
import sys, os, signal
from pathlib import Path
from edge.publish.spool import DiskSpool
from edge.samples import Sample, MetricType
spool = DiskSpool(Path(sys.argv[1]))
for i in range(int(sys.argv[2])):
    spool.hold("sparkplug", "m1", "data", [Sample("Macro/1", i, MetricType.INT32, i)])
print("held", flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_kill_9_after_hold_loses_nothing(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    proc = subprocess.run([sys.executable, "-c", CHILD, str(path), "300"], capture_output=True, timeout=60,
                          cwd=Path(__file__).parents[3], env={**os.environ, "PYTHONPATH": "."})
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert b"held" in proc.stdout
    spool = DiskSpool(path)
    values = [s.value for e in spool.oldest("sparkplug", 1000) for s in e.samples]
    assert values == list(range(300))
    spool.close()


values = st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.text(),
                   st.floats(allow_nan=False))


@given(st.lists(st.tuples(st.text(min_size=1), values, st.sampled_from(list(MetricType)),
                          st.integers(0, 2**48), st.sampled_from(list(Quality))), max_size=20))
def test_encode_decode_round_trip_property(rows: list[tuple[str, object, MetricType, int, Quality]]) -> None:
    samples = [Sample(*row) for row in rows]
    assert decode_samples(encode_samples(samples)) == samples
    assert decode_samples(encode_samples(samples), historical=True) == [Sample(*row, True) for row in rows]


@given(st.binary(max_size=200))
def test_decode_garbage_raises_value_error_only_fuzz(body: bytes) -> None:
    with contextlib.suppress(ValueError):
        decode_samples(body)


def _record(outbox: Outbox, batch: HeldBatch) -> None:
    """The outbox remembers a sent batch by its parts, as the live path hands them."""
    outbox.add(batch.device_id, batch.kind, batch.samples)


def test_outbox_confirms_up_to_the_mark_and_gives_back_the_rest() -> None:
    outbox = Outbox()
    batches = [HeldBatch("m1", "data", [sample(i)]) for i in range(4)]
    _record(outbox, batches[0])
    _record(outbox, batches[1])
    mark = outbox.mark()
    _record(outbox, batches[2])
    assert outbox.confirm(mark) == 2
    _record(outbox, batches[3])
    assert outbox.take_all() == batches[2:]
    assert len(outbox) == 0


def test_forwarding_policy_validates() -> None:
    with pytest.raises(ValueError, match="positive"):
        ForwardingPolicy(probe_timeout_s=0)


def test_the_rate_rows_were_spooled_at_is_what_a_replay_paces_from(tmp_path: Path) -> None:
    clock = Clock()
    spool = DiskSpool(tmp_path / "s.sqlite", clock=clock)
    spool.hold("sparkplug", "m1", "data", [sample(0)])
    assert spool.spooled_rate("sparkplug") is None, "one row has no rate"
    for i in range(1, 61):  # a 60 s outage of a machine ticking twice a second
        clock.now += 0.5
        spool.hold("sparkplug", f"m{i % 2}", "data", [sample(i)])
    assert spool.spooled_rate("sparkplug") == 61 / 30
    assert spool.spooled_rate("json") is None
    spool.close()


@pytest.mark.parametrize("content", [b"\x00garbage" * 4096, b"SQLite format 3\x00" + bytes(range(256)) * 20],
                         ids=["not-a-database", "malformed"])
def test_a_corrupt_spool_file_is_moved_aside_and_a_new_spool_keeps_samples(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, content: bytes) -> None:
    """Without this every restart met the same file and spooled nothing: the next outage lost its samples."""
    (tmp_path / "spool.sqlite").write_bytes(content)
    with caplog.at_level(logging.ERROR, logger="edge.publish.spool"):
        spool = open_spool(tmp_path, 16 * 1024 * 1024, 3600.0)
    try:
        assert isinstance(spool, DiskSpool)
        kept = [p for p in tmp_path.iterdir() if p.name.startswith("spool.sqlite.corrupt-")]
        assert [p.read_bytes() for p in kept] == [content]
        assert "spool file is corrupt" in caplog.text and kept[0].name in caplog.text
        spool.hold("sparkplug", "m1", "data", [Sample("Macro/500", 1.5, MetricType.DOUBLE, 1_700_000_000_000)])
        assert spool.pending("sparkplug") == 1
    finally:
        spool.close()


def committed_rows(path: Path) -> int:
    """Rows another connection sees: what a kill -9 now would leave."""
    with contextlib.closing(sqlite3.connect(str(path))) as db:
        return int(db.execute("SELECT COUNT(*) FROM spool").fetchone()[0])


async def test_on_a_loop_the_rows_of_one_turn_are_committed_together_when_it_ends(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    spool = DiskSpool(path)
    for i in range(200):
        spool.hold("sparkplug", f"m{i % 7}", "data", [sample(i)])
    assert committed_rows(path) == 0, "one transaction at the end of the turn, not one per row"
    await asyncio.sleep(0)  # the turn ends
    assert committed_rows(path) == 200
    spool.hold("sparkplug", "m1", "data", [sample(200)])
    assert spool.pending() == 201, "a read sees the rows of the current turn"
    entries = spool.oldest("sparkplug", 1000)
    assert [e.samples[0].value for e in entries] == [float(i) for i in range(201)]
    spool.hold("sparkplug", "m1", "data", [sample(201)])
    spool.close()  # saves what the turn held
    again = DiskSpool(path)
    assert again.pending() == 202
    again.close()


def test_lazy_entries_give_the_stored_rows_and_the_same_samples(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite")
    held = [sample(1), Sample("Mode", "AUTO", MetricType.STRING, 7, Quality.STALE)]
    spool.hold("sparkplug", "m1", "data", held)
    (entry,) = spool.oldest("sparkplug", 10, lazy=True)
    assert entry.rows() == [[s.name, s.value, s.type.value, s.timestamp_ms, int(s.quality)] for s in held]
    assert entry.samples == [Sample(s.name, s.value, s.type, s.timestamp_ms, s.quality, True) for s in held]
    assert entry == spool.oldest("sparkplug", 10)[0], "lazy or not, the same entry"
    spool.close()


def test_a_lazy_row_not_shaped_as_written_has_no_rows_and_a_reader_may_drop_it(tmp_path: Path) -> None:
    spool = DiskSpool(tmp_path / "s.sqlite")
    spool.hold("sparkplug", "m1", "data", [sample(1)])
    db = spool._conn()
    db.execute("UPDATE spool SET body = ?", (b'[["Macro/500", 1.0, "Double", 5.0, 192, "extra"]]',))
    (six,) = spool.oldest("sparkplug", 10, lazy=True)
    assert six.rows() is None, "six columns: not a row"
    with pytest.raises(ValueError, match="expected a JSON list"):
        six.samples  # noqa: B018 (the property reads the body)
    spool.unreadable(six.id, ValueError("six columns"))
    assert spool.dropped == 1 and spool.pending() == 0
    spool.hold("sparkplug", "m1", "data", [sample(2)])
    db.execute("UPDATE spool SET body = ?", (b'[["Macro/500", 2.0, "Double", 5.0, 192]]',))
    (lenient,) = spool.oldest("sparkplug", 10, lazy=True)
    assert lenient.rows() is not None and lenient.samples[0].timestamp_ms == 5, "a float timestamp: read leniently"
    spool.close()


def test_row_ids_by_device_then_bodies_read_in_parts(tmp_path: Path) -> None:
    """The Sparkplug replay's reads: a step's ids by device (oldest first, only after `after`, only the
    devices asked for), then the rows of some of them, lazy, in id order; a row gone meanwhile is left out."""
    spool = DiskSpool(tmp_path / "s.sqlite")
    for i, device in enumerate(["m1", "m2", "m1", "m3", "m2"]):
        spool.hold("sparkplug", device, "data", [Sample("x", float(i), MetricType.DOUBLE, i)])
    spool.hold("json", "m1", "data", [Sample("x", 9.0, MetricType.DOUBLE, 9)])
    ids = spool.oldest_ids("sparkplug", 10)
    assert list(ids) == ["m1", "m2", "m3"] and [len(v) for v in ids.values()] == [2, 2, 1]
    assert spool.oldest_ids("sparkplug", 3) == {"m1": ids["m1"], "m2": ids["m2"][:1]}
    assert spool.oldest_ids("sparkplug", 10, devices={"m2"}) == {"m2": ids["m2"]}
    assert spool.oldest_ids("sparkplug", 10, devices=set()) == {}
    assert spool.oldest_ids("sparkplug", 10, after=ids["m1"][1]) == {"m3": ids["m3"], "m2": ids["m2"][1:]}
    spool.ack([ids["m1"][0]])
    entries = spool.read("sparkplug", sorted(ids["m2"] + ids["m1"]))
    assert [(e.id, e.device_id) for e in entries] == sorted([(i, "m2") for i in ids["m2"]] + [(ids["m1"][1], "m1")])
    assert [s.value for e in entries for s in e.samples] == [1.0, 2.0, 4.0]
    assert all(s.historical for e in entries for s in e.samples)


def _sqlite_heap() -> int:
    """Bytes SQLite has malloc'd in this process (its page caches and prepared statements)."""
    try:
        used = ctypes.CDLL("libsqlite3.so.0").sqlite3_memory_used
    except (OSError, AttributeError):
        pytest.skip("no shared libsqlite3 to ask")
    used.restype = ctypes.c_int64
    return int(used())


def test_reads_of_many_lengths_keep_few_prepared_statements(tmp_path: Path) -> None:
    """A replay reads, acks and queries lists of every length; one statement text per query keeps SQLite's
    cache of prepared statements small (one per list length held ~21 MB at 1,000 machines)."""
    spool = DiskSpool(tmp_path / "s.sqlite")
    devices = ['Hallé "3" \\ 😀'] + [f"m{i:03d}" for i in range(1, 400)]  # names pass through JSON unchanged
    for device in devices:
        spool.hold("sparkplug", device, "data", [sample(1)])
    ids = [i for row_ids in spool.oldest_ids("sparkplug", 400).values() for i in row_ids]
    spool.read("sparkplug", ids[:10])
    before = _sqlite_heap()
    for n in range(200, 400):
        assert len(spool.read("sparkplug", sorted(ids[:n]))) == n
        assert len(spool.oldest_ids("sparkplug", n, devices=devices[:n])) == n
    assert _sqlite_heap() - before < 1_000_000
    spool.ack(ids)
    assert spool.pending() == 0
    spool.close()


def test_an_outage_s_rows_leave_no_more_than_the_bounded_page_cache(tmp_path: Path) -> None:
    """SQLite's page cache stays under its bound while megabytes are spooled, and is given back when the
    spool empties (the default cache, 2 MB, stayed filled with the pages of rows long gone)."""
    spool = DiskSpool(tmp_path / "s.sqlite")
    before = _sqlite_heap()
    values = [sample(i, f"Macro/{500 + i}") for i in range(16)]
    for device in range(4000):
        spool.hold("sparkplug", f"m{device % 100:03d}", "data", values)
    assert spool.bytes > 2_000_000
    assert _sqlite_heap() - before < 800_000
    while rows := spool.oldest("sparkplug", 500):
        spool.ack([e.id for e in rows])
    assert _sqlite_heap() - before < 200_000
    spool.close()
