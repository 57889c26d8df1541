"""The store-and-forward spool: samples that could not be published wait on disk until the broker is back.

SQLite in WAL mode, one row per held batch (one tick's changes or one set of alarm events), oldest first by
row id. A committed row survives kill -9 (WAL, synchronous=NORMAL; a power cut may lose the last few
commits). Rows leave the spool only when the publisher acknowledges them after a delivery barrier, so a
crash during replay sends them again: at-least-once, consumers drop duplicates by key (docs/reliability.md).

Bounds and drop policy (both counted in `dropped`, logged once per burst):
- age: rows spooled more than `max_age_s` ago are deleted, oldest first;
- size: when the payload bytes would exceed `max_bytes`, the oldest *data* rows go first; alarm events are
  kept as long as any data row is left to drop, then the oldest events go. The newest values are never
  lost by this: births always carry each metric's latest value.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from edge.samples import MetricType, Quality, Sample

log = logging.getLogger(__name__)

Format = Literal["sparkplug", "json"]
SampleKind = Literal["data", "events"]
FILE_NAME = "spool.sqlite"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS spool (
    id      INTEGER PRIMARY KEY AUTOINCREMENT,
    fmt     TEXT    NOT NULL,
    device  TEXT    NOT NULL,
    kind    TEXT    NOT NULL,
    created REAL    NOT NULL,
    size    INTEGER NOT NULL,
    body    BLOB    NOT NULL
);
CREATE INDEX IF NOT EXISTS spool_fmt ON spool (fmt, id);
CREATE INDEX IF NOT EXISTS spool_created ON spool (created);
"""


@dataclass(frozen=True, slots=True)
class SpoolEntry:
    """One held batch: what `hold` was given, with its row id (the replay order and the ack key)."""

    id: int
    fmt: Format
    device_id: str
    kind: SampleKind
    samples: list[Sample]


def encode_samples(samples: Sequence[Sample]) -> bytes:
    """Samples as compact JSON rows [name, value, type, ts, quality]; unknown value types become text."""
    rows = [[s.name, s.value, s.type.value, s.timestamp_ms, int(s.quality)] for s in samples]
    return json.dumps(rows, separators=(",", ":"), default=str).encode("utf-8")


def decode_samples(body: bytes) -> list[Sample]:
    """The inverse of encode_samples; ValueError (with what came) for a body that is not one."""
    try:
        rows = json.loads(body)
        return [Sample(str(name), value, MetricType(kind), int(ts), Quality(int(quality)))
                for name, value, kind, ts, quality in rows]
    except (TypeError, ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"spool row: expected a JSON list of [name, value, type, ts, quality], "
                         f"got {body[:60]!r}: {exc}") from exc


class DiskSpool:
    """The `Spool` the publisher holds undeliverable samples in, with replay reads and acks.

    Used from the event loop thread only (each call is one short transaction); a lock guards against
    accidental use from another thread.
    """

    def __init__(self, path: Path, *, max_bytes: int = 256 * 1024 * 1024, max_age_s: float = 7 * 24 * 3600.0,
                 clock: Callable[[], float] = time.time) -> None:
        if max_bytes <= 0 or max_age_s <= 0:
            raise ValueError(f"spool bounds: expected max_bytes > 0 and max_age_s > 0, "
                             f"got {max_bytes} and {max_age_s}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.max_bytes = int(max_bytes)
        self.max_age_s = float(max_age_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._db: sqlite3.Connection | None = sqlite3.connect(str(self.path), isolation_level=None,
                                                               check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(_SCHEMA)
        row = self._db.execute("SELECT COUNT(*), COALESCE(SUM(size), 0) FROM spool").fetchone()
        self._rows, self.bytes = int(row[0]), int(row[1])
        self.dropped = 0  # samples lost to the bounds (or unreadable rows), since this process started
        self.held = 0  # samples accepted by hold()
        self._dropping = False  # inside a burst of drops (log once per burst)
        if self._rows:
            log.info("spool opened with rows waiting path=%s rows=%d bytes=%d", self.path, self._rows,
                     self.bytes)

    # -- the Spool protocol --------------------------------------------------------------------------

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None:
        """Append one batch (committed before returning), then enforce the bounds."""
        if not samples:
            return
        body = encode_samples(samples)
        with self._lock:
            db = self._conn()
            db.execute("INSERT INTO spool (fmt, device, kind, created, size, body) VALUES (?, ?, ?, ?, ?, ?)",
                       (fmt, device_id, kind, self._clock(), len(body), body))
            self._rows += 1
            self.bytes += len(body)
            self.held += len(samples)
            self._enforce_bounds(db)

    # -- replay --------------------------------------------------------------------------------------

    def pending(self, fmt: Format | None = None) -> int:
        """Rows waiting (for one format, or all)."""
        with self._lock:
            db = self._conn()
            if fmt is None:
                return self._rows
            return int(db.execute("SELECT COUNT(*) FROM spool WHERE fmt = ?", (fmt,)).fetchone()[0])

    def oldest(self, fmt: Format, limit: int, devices: Collection[str] | None = None) -> list[SpoolEntry]:
        """Up to `limit` rows of one format, oldest first; only those `devices` if given.

        A row whose body cannot be read is deleted and counted as dropped (it would block replay forever).
        """
        with self._lock:
            db = self._conn()
            self._enforce_age(db)
            if devices is None:
                rows = db.execute("SELECT id, device, kind, body FROM spool WHERE fmt = ? ORDER BY id LIMIT ?",
                                  (fmt, limit)).fetchall()
            else:
                wanted = sorted(devices)
                if not wanted:
                    return []
                marks = ",".join("?" * len(wanted))
                rows = db.execute(f"SELECT id, device, kind, body FROM spool WHERE fmt = ? AND device IN "
                                  f"({marks}) ORDER BY id LIMIT ?", (fmt, *wanted, limit)).fetchall()
            out: list[SpoolEntry] = []
            for row_id, device, kind, body in rows:
                try:
                    samples = decode_samples(bytes(body))
                except ValueError as exc:
                    log.error("unreadable spool row deleted id=%d error=%s", row_id, exc)
                    self._delete(db, [row_id])
                    self.dropped += 1
                    continue
                out.append(SpoolEntry(int(row_id), fmt, str(device), "events" if kind == "events" else "data",
                                      samples))
            return out

    def ack(self, ids: Sequence[int]) -> None:
        """These rows reached the broker: delete them."""
        if not ids:
            return
        with self._lock:
            self._delete(self._conn(), list(ids))

    def flush(self) -> None:
        """Checkpoint the WAL into the main file (shutdown; every hold is already committed)."""
        with self._lock:
            if self._db is not None:
                self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def close(self) -> None:
        with self._lock:
            db, self._db = self._db, None
            if db is not None:
                try:
                    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                finally:
                    db.close()

    # -- internals -----------------------------------------------------------------------------------

    def _conn(self) -> sqlite3.Connection:
        if self._db is None:
            raise RuntimeError(f"spool {self.path} is closed")
        return self._db

    def _delete(self, db: sqlite3.Connection, ids: list[int]) -> None:
        for start in range(0, len(ids), 500):
            chunk = ids[start:start + 500]
            marks = ",".join("?" * len(chunk))
            row = db.execute(f"SELECT COUNT(*), COALESCE(SUM(size), 0) FROM spool WHERE id IN ({marks})",
                             chunk).fetchone()
            db.execute(f"DELETE FROM spool WHERE id IN ({marks})", chunk)
            self._rows -= int(row[0])
            self.bytes -= int(row[1])

    def _enforce_bounds(self, db: sqlite3.Connection) -> None:
        dropped = self._enforce_age(db)
        while self.bytes > self.max_bytes and self._rows > 0:
            victim = db.execute("SELECT id, body FROM spool WHERE kind = 'data' ORDER BY id LIMIT 64").fetchall()
            if not victim:
                victim = db.execute("SELECT id, body FROM spool ORDER BY id LIMIT 64").fetchall()
            for row_id, body in victim:
                if self.bytes <= self.max_bytes:
                    break
                self._delete(db, [row_id])
                dropped += _sample_count(bytes(body))
        self._count_drops(dropped, "size")

    def _enforce_age(self, db: sqlite3.Connection) -> int:
        cutoff = self._clock() - self.max_age_s
        rows = db.execute("SELECT id, body FROM spool WHERE created < ? ORDER BY id", (cutoff,)).fetchall()
        if not rows:
            return 0
        self._delete(db, [r[0] for r in rows])
        dropped = sum(_sample_count(bytes(r[1])) for r in rows)
        self._count_drops(dropped, "age")
        return 0

    def _count_drops(self, samples: int, reason: str) -> None:
        if samples <= 0:
            self._dropping = False
            return
        self.dropped += samples
        if not self._dropping:
            log.warning("spool full, dropping oldest samples reason=%s dropped_total=%d max_bytes=%d "
                        "max_age_s=%s", reason, self.dropped, self.max_bytes, self.max_age_s)
        self._dropping = True


def _sample_count(body: bytes) -> int:
    try:
        rows = json.loads(body)
    except ValueError:
        return 1
    return len(rows) if isinstance(rows, list) else 1


def open_spool(state_dir: Path, max_bytes: int, max_age_s: float) -> DiskSpool:
    """The daemon's spool: `spool.sqlite` in the state directory."""
    return DiskSpool(Path(state_dir) / FILE_NAME, max_bytes=max_bytes, max_age_s=max_age_s)
