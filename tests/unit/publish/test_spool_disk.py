"""Full disk (issue 16, points 6-8): state_dir on a 1 MB tmpfs. bdSeq, the spool's bound and drops, acks."""

from __future__ import annotations

import contextlib
import logging
import sqlite3
from dataclasses import replace
from pathlib import Path

import pytest

from edge.publish.bdseq import BdSeqCounter
from edge.publish.spool import DiskSpool, UnopenedSpool, open_spool
from edge.publish.state_store import StateStore
from edge.samples import MetricType, Sample
from tests.small_disk import disk_use, fill, small_disk


def test_bdseq_on_a_full_disk_is_used_anyway_warned_and_counted(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with small_disk(tmp_path / "state") as state:
        store = StateStore(state)
        counter = BdSeqCounter(store)
        assert counter.next_for_connect() == 0
        fill(state)
        with caplog.at_level(logging.WARNING, logger="edge.publish.bdseq"):
            assert counter.next_for_connect() == 1
            assert counter.next_for_connect() == 2
        assert counter.persist_failures == 2
        assert counter.current == 2
        assert "bdSeq not persisted" in caplog.text
        assert (store.load("sparkplug_bdseq") or {}).get("last") == 0  # the last value that fit
        assert not [p for p in state.iterdir() if p.name.startswith(".")], "a temp file was left behind"


def batch(i: int, metrics: int = 6) -> list[Sample]:
    """About 260 bytes of payload: one tick of one machine."""
    return [Sample(f"Macro/{500 + m}", float(i * 10 + m), MetricType.DOUBLE, 1_700_000_000_000 + i)
            for m in range(metrics)]


def spool_files(path: Path) -> list[Path]:
    return [path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-journal"),
            path.with_name(path.name + ".headroom")]


def samples_left(spool: DiskSpool) -> int:
    return sum(len(e.samples) for e in spool.oldest("sparkplug", 1_000_000))


def rows_on_disk(path: Path) -> int:
    with contextlib.closing(sqlite3.connect(str(path))) as db:
        return int(db.execute("SELECT COUNT(*) FROM spool").fetchone()[0])


def test_spool_on_a_full_1mb_disk_drops_oldest_counts_every_sample_and_logs_once(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with small_disk(tmp_path / "state") as state:
        spool = DiskSpool(state / "spool.sqlite")  # max_bytes (256 MiB) far above the disk
        with caplog.at_level(logging.WARNING, logger="edge.publish.spool"):
            for i in range(3000):
                spool.hold("sparkplug", "m1", "data", batch(i))
        assert spool.held == 3000 * 6
        assert spool.dropped > 0, "a 1 MB disk cannot hold 3000 rows: something must have been dropped"
        left = samples_left(spool)
        assert spool.dropped + left == spool.held, "every sample is either waiting or counted as dropped"
        newest = spool.oldest("sparkplug", 1_000_000)[-1]
        assert newest.samples == [replace(s, historical=True) for s in batch(2999)], \
            "the newest rows are kept (oldest first is dropped), handed out historical"
        starts = [r for r in caplog.records if "spool full" in r.getMessage()]
        assert len(starts) == 1, f"one log line per episode, got {len(starts)}"
        spool.close()


def test_acks_delete_rows_on_a_full_disk(tmp_path: Path) -> None:
    with small_disk(tmp_path / "state") as state:
        spool = DiskSpool(state / "spool.sqlite")
        for i in range(3000):
            spool.hold("sparkplug", "m1", "data", batch(i))
        fill(state)  # whatever the spool left free is gone too
        entries = spool.oldest("sparkplug", 100)
        spool.ack([e.id for e in entries])
        assert spool.oldest("sparkplug", 1)[0].id > entries[-1].id, "acked rows are never handed out again"
        waiting = spool.pending()
        assert rows_on_disk(state / "spool.sqlite") == waiting, "the acked rows were deleted on disk"
        rest = spool.oldest("sparkplug", 1_000_000)
        spool.ack([e.id for e in rest])
        assert spool.pending() == 0 and rows_on_disk(state / "spool.sqlite") == 0
        spool.close()


def test_spool_disk_use_stays_within_max_bytes_counting_wal_and_journal(tmp_path: Path) -> None:
    with small_disk(tmp_path / "state", "8m") as state:
        path = state / "spool.sqlite"
        spool = DiskSpool(path, max_bytes=1024 * 1024)
        peak = 0
        for i in range(5000):
            spool.hold("sparkplug", "m1", "data", batch(i))
            if i % 25 == 0:
                peak = max(peak, disk_use(*spool_files(path)))
        assert peak <= 1024 * 1024, f"spool files took {peak} bytes, max_bytes is 1 MiB"
        assert spool.dropped > 0
        assert spool.dropped + samples_left(spool) == spool.held
        print(f"\nFIGURES spool 1 MiB bound: rows_kept={spool.pending()} peak_bytes={peak} "
              f"dropped_samples={spool.dropped}")
        spool.close()


def test_a_spool_that_cannot_be_opened_counts_drops_instead_of_stopping_the_daemon(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with small_disk(tmp_path / "state") as state:
        spool = open_spool(state, 256 * 1024 * 1024, 3600.0)
        for i in range(3000):
            spool.hold("sparkplug", "m1", "data", batch(i))
        spool.close()
        fill(state)  # not a byte left: SQLite cannot even create its WAL index
        with caplog.at_level(logging.ERROR, logger="edge.publish.spool"):
            again = open_spool(state, 256 * 1024 * 1024, 3600.0)
            again.hold("sparkplug", "m1", "data", batch(1))
        assert isinstance(again, UnopenedSpool), "the spool opened on a disk without a free byte?"
        assert again.dropped == 6 and again.pending() == 0 and again.oldest("sparkplug", 10) == []
        assert "spool cannot be opened" in caplog.text
        again.close()
