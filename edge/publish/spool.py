"""The store-and-forward spool: samples that could not be published wait on disk until the broker is back.

SQLite in WAL mode, one row per held batch (one tick's changes or one set of alarm events), oldest first by
row id. A committed row survives kill -9 (WAL, synchronous=NORMAL; a power cut may lose the last few
commits). On an event loop, every row held during one loop turn is committed in one transaction at the end
of that turn (a commit costs ~130 us, a row in a shared one ~12 us: 1,000 machines spool 1,000 rows a second
while the broker is away); a kill -9 inside the turn loses that turn's rows, as it loses the samples of a
tick not yet held. Without a running loop each hold commits before it returns.

Rows leave the spool only when the publisher acknowledges them after a delivery barrier, so a crash during replay
sends them again: at-least-once, consumers drop duplicates by key (docs/reliability.md).

Bounds and drop policy (every dropped sample counted in `dropped`, logged once per episode):
- age: rows spooled more than `max_age_s` ago are deleted, oldest first;
- disk: the files (database + WAL + journal + the headroom file) stay within `max_bytes` (edge.publish.
  spool_disk.DiskBudget: a page cap on the database, a checkpointed and size-limited WAL) and within the
  disk itself. When a row does not fit (the cap or a full disk: SQLITE_FULL), the oldest rows are dropped
  to make room, by the same order as for size;
- size: the payload bytes stay within `max_bytes` too (what bounds a tiny spool);
- order: the oldest *data* rows go first; alarm events are kept as long as any data row is left to drop,
  then the oldest events go. The newest values are never lost by this: births carry each latest value.
A DELETE needs WAL space, so a headroom file is released when the disk is full; acknowledged rows that
still cannot be deleted are remembered and never replayed again, and their delete is retried.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import sqlite3
import threading
import time
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from edge.publish.spool_disk import DiskBudget, Headroom, disk_budget, filesystem_bytes, is_full
from edge.publish.spool_rows import Format, SampleKind, SpoolEntry, encode_samples, read_entry
from edge.samples import Sample

log = logging.getLogger(__name__)

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
class _Unsaved:
    """A row held and not yet committed."""

    row: tuple[object, ...]
    fmt: str
    size: int
    samples: int


class DiskSpool:
    """The `Spool` the publisher holds undeliverable samples in, with replay reads and acks.

    Used from the event loop thread only (each call is one short transaction); a lock guards against
    accidental use from another thread. A full disk never raises out of hold() or ack(): it drops by the
    policy (counted) or keeps an ack to retry.
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
        headroom_path = self.path.with_name(self.path.name + ".headroom")
        headroom_path.unlink(missing_ok=True)  # the last run's headroom: room to open on a full disk
        self._db: sqlite3.Connection | None = sqlite3.connect(str(self.path), isolation_level=None,
                                                               check_same_thread=False)
        page_size = int(self._db.execute("PRAGMA page_size").fetchone()[0])
        self.budget: DiskBudget = disk_budget(self.max_bytes, page_size, filesystem_bytes(self.path.parent))
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute(f"PRAGMA cache_size=-{_CACHE_KIB}")
        self._db.execute(f"PRAGMA wal_autocheckpoint={self.budget.wal_checkpoint_pages}")
        self._db.execute(f"PRAGMA journal_size_limit={self.budget.wal_bytes}")
        self._db.executescript(_SCHEMA)
        self._cap_pages(self.budget.db_pages)
        self.headroom = Headroom(headroom_path, self.budget.headroom_bytes)
        self.headroom.take()
        self._rows: Counter[str] = Counter()
        self.bytes = 0
        for fmt, count, size in self._db.execute("SELECT fmt, COUNT(*), COALESCE(SUM(size), 0) FROM spool "
                                                  "GROUP BY fmt"):
            self._rows[str(fmt)] = int(count)
            self.bytes += int(size)
        self._acked: dict[int, str] = {}  # acknowledged rows whose DELETE failed (full disk): id -> format
        self.dropped = 0  # samples lost to the bounds (or unreadable rows), since this process started
        self.held = 0  # samples given to hold() (kept or dropped)
        self._episode_dropped: int | None = None  # samples dropped in the current drop episode, or None
        self._unsaved: list[_Unsaved] = []  # the rows held in this loop turn
        self._save_scheduled = False
        if self._rows:
            log.info("spool opened with rows waiting path=%s rows=%d bytes=%d", self.path,
                     sum(self._rows.values()), self.bytes)

    # -- the Spool protocol --------------------------------------------------------------------------

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None:
        """Append one batch (committed at the end of this loop turn, or before returning without a loop),
        dropping the oldest rows when it does not fit."""
        if not samples:
            return
        body = encode_samples(samples)
        with self._lock:
            self._conn()
            self.held += len(samples)
            row = (fmt, device_id, kind, self._clock(), len(body), body)
            self._unsaved.append(_Unsaved(row, fmt, len(body), len(samples)))
            if not self._save_at_turn_end():
                self._save()

    def _save_at_turn_end(self) -> bool:
        """Commit the rows held in this loop turn once it ends; False without a running loop."""
        if self._save_scheduled:
            return True
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return False
        self._save_scheduled = True
        loop.call_soon(self._save_turn)
        return True

    def _save_turn(self) -> None:
        with self._lock:
            self._save_scheduled = False
            if self._db is None:
                return
            count = sum(u.samples for u in self._unsaved)
            try:
                self._save()
            except sqlite3.Error as exc:  # not a full disk (that drops by the policy): the turn's rows are lost
                self._unsaved.clear()
                self.dropped += count
                log.error("spool write failed, samples lost samples=%d dropped_total=%d path=%s error=%s",
                          count, self.dropped, self.path, exc)

    def _save(self) -> None:
        """Commit the rows held and not yet saved: one transaction, or row by row when the disk is full."""
        rows, self._unsaved = self._unsaved, []
        if not rows:
            return
        db = self._conn()
        self._retry_acked(db)
        if self._insert_all(db, [u.row for u in rows]):
            saved = rows
        else:
            saved = []
            for u in rows:
                if self._insert(db, u.row):
                    saved.append(u)
                else:
                    self._count_drops(u.samples, "disk")  # nothing older left to drop, or no delete fits
        for u in saved:
            self._rows[u.fmt] += 1
            self.bytes += u.size
        if saved:
            self._enforce_bounds(db)
            self._recover_headroom()

    # -- replay --------------------------------------------------------------------------------------

    @property
    def depth(self) -> int:
        """Rows waiting to be replayed (both formats): the spool-depth gauge."""
        return self.pending()

    def pending(self, fmt: Format | None = None) -> int:
        """Rows waiting (for one format, or all); acknowledged rows not yet deleted are not waiting."""
        with self._lock:
            if self._db is not None:
                self._save()
            if fmt is None:
                return sum(self._rows.values()) - len(self._acked)
            return self._rows[fmt] - sum(1 for f in self._acked.values() if f == fmt)

    def spooled_rate(self, fmt: Format) -> float | None:
        """Rows per second at which the waiting rows of one format were spooled (None under 2 rows or 1 s)."""
        with self._lock:
            self._save()
            count, first, last = self._conn().execute(
                "SELECT COUNT(*), MIN(created), MAX(created) FROM spool WHERE fmt = ?", (fmt,)).fetchone()
        if count < 2 or last - first < 1.0:
            return None
        return float(count / (last - first))

    def oldest(self, fmt: Format, limit: int, devices: Collection[str] | None = None, *,
               lazy: bool = False, after: int = 0) -> list[SpoolEntry]:
        """Up to `limit` rows of one format, oldest first; only those `devices` if given; only rows after
        row id `after` (those before are in flight); `lazy`: read by the caller (edge.publish.spool_rows.
        read_entry).

        A row whose body cannot be read is deleted and counted as dropped (it would block replay forever).
        """
        with self._lock:
            db = self._conn()
            cursor = self._oldest_rows(db, "id, device, kind, body", fmt, limit, devices, after)
            if cursor is None:
                return []
            rows = cursor.fetchall()
            out: list[SpoolEntry] = []
            for row_id, device, kind, body in rows:
                if row_id in self._acked or len(out) >= limit:
                    continue
                try:
                    out.append(read_entry(int(row_id), fmt, str(device), "events" if kind == "events" else "data",
                                          bytes(body), lazy=lazy))
                except ValueError as exc:
                    self._drop_unreadable(db, int(row_id), exc)
            return out

    def oldest_ids(self, fmt: Format, limit: int, devices: Collection[str] | None = None, *,
                   after: int = 0) -> dict[str, list[int]]:
        """`oldest` without the bodies: the ids of up to `limit` rows by device (each device's oldest first,
        devices in the order of their first row), for a replay that reads the bodies a few devices at a
        time (`read`): a step of ~9,000 rows of ~1 kB read at once is ~9 MB of short-lived blocks, which
        the live ticks' allocations in between leave as a fragmented heap."""
        with self._lock:
            cursor = self._oldest_rows(self._conn(), "id, device", fmt, limit, devices, after)
            if cursor is None:
                return {}
            out: dict[str, list[int]] = {}
            acked, taken = self._acked, 0
            for row_id, device in cursor:
                if taken >= limit:
                    break
                if row_id in acked:
                    continue
                ids = out.get(device)
                if ids is None:
                    out[device] = ids = []
                ids.append(row_id)
                taken += 1
            return out

    def _oldest_rows(self, db: sqlite3.Connection, columns: str, fmt: Format, limit: int,
                     devices: Collection[str] | None, after: int) -> sqlite3.Cursor | None:
        """The oldest rows' `columns` for `oldest` and `oldest_ids` (the lock held): what is pending saved,
        acked rows retried, the age bound kept first; `limit` plus the acked rows (skipped by the caller);
        None when `devices` names none."""
        self._save()
        self._retry_acked(db)
        self._enforce_age(db)
        want = limit + len(self._acked)
        if devices is None:
            return db.execute(f"SELECT {columns} FROM spool WHERE fmt = ? AND id > ? ORDER BY id LIMIT ?",
                              (fmt, after, want))
        wanted = sorted(devices)
        if not wanted:
            return None
        return db.execute(f"SELECT {columns} FROM spool WHERE fmt = ? AND id > ? AND device IN {_LISTED} "
                          f"ORDER BY id LIMIT ?", (fmt, after, _listed(wanted), want))

    def read(self, fmt: Format, ids: Sequence[int]) -> list[SpoolEntry]:
        """These rows (ids from `oldest_ids`) as lazy entries (edge.publish.spool_rows.read_entry), in id
        order; a row gone meanwhile (the age bound) is left out."""
        if not ids:
            return []
        with self._lock:
            rows = self._conn().execute(f"SELECT id, device, kind, body FROM spool WHERE id IN {_LISTED} "
                                        f"ORDER BY id", (_listed(ids),)).fetchall()
            return [read_entry(int(row_id), fmt, str(device), "events" if kind == "events" else "data",
                               bytes(body), lazy=True) for row_id, device, kind, body in rows]

    def unreadable(self, row_id: int, error: Exception) -> None:
        """A row handed out that its reader could not read: deleted and counted, as `oldest` does."""
        with self._lock:
            self._drop_unreadable(self._conn(), row_id, error)

    def _drop_unreadable(self, db: sqlite3.Connection, row_id: int, error: Exception) -> None:
        log.error("unreadable spool row deleted id=%d error=%s", row_id, error)
        self._delete(db, [row_id])
        self.dropped += 1

    def ack(self, ids: Sequence[int]) -> None:
        """These rows reached the broker: delete them (or, on a full disk, never hand them out again)."""
        if not ids:
            return
        with self._lock:
            db = self._conn()
            for row_id, fmt in db.execute(f"SELECT id, fmt FROM spool WHERE id IN {_LISTED}", (_listed(ids),)):
                self._acked[int(row_id)] = str(fmt)
            self._retry_acked(db)
            self._recover_headroom()
            if not sum(self._rows.values()):
                self._end_episode()
                db.execute("PRAGMA shrink_memory")  # the page cache's pages of rows now gone

    def flush(self) -> None:
        """Checkpoint the WAL into the main file (shutdown; every hold is already committed)."""
        with self._lock:
            if self._db is not None:
                self._save()
                self._checkpoint(self._db, "TRUNCATE")

    def close(self) -> None:
        with self._lock:
            if self._db is not None:
                self._save()
            db, self._db = self._db, None
            if db is not None:
                try:
                    self._checkpoint(db, "TRUNCATE")
                finally:
                    db.close()

    # -- internals -----------------------------------------------------------------------------------

    def _conn(self) -> sqlite3.Connection:
        if self._db is None:
            raise RuntimeError(f"spool {self.path} is closed")
        return self._db

    def _insert_all(self, db: sqlite3.Connection, rows: list[tuple[object, ...]]) -> bool:
        """INSERT the rows in one transaction; False (nothing inserted) when the disk or the cap is full."""
        try:
            db.execute("BEGIN")
            db.executemany(_INSERT, rows)
            db.execute("COMMIT")
        except sqlite3.OperationalError as exc:
            if db.in_transaction:
                with contextlib.suppress(sqlite3.Error):
                    db.execute("ROLLBACK")
            if not is_full(exc):
                raise
            return False
        return True

    def _insert(self, db: sqlite3.Connection, row: tuple[object, ...]) -> bool:
        """INSERT the row; on SQLITE_FULL drop the oldest rows to make room and try again."""
        for _ in range(_ROOM_ATTEMPTS):
            try:
                db.execute(_INSERT, row)
                return True
            except sqlite3.OperationalError as exc:
                if not is_full(exc):
                    raise
            if not self._make_room(db):
                return False
        return False

    def _make_room(self, db: sqlite3.Connection) -> bool:
        """The row did not fit: stop the file growing, free the headroom, drop the oldest rows."""
        self._cap_pages(int(db.execute("PRAGMA page_count").fetchone()[0]))  # reuse freed pages from now
        self.headroom.release()
        try:
            dropped = self._drop_oldest(db, _ROOM_ROWS)
        except sqlite3.OperationalError as exc:
            if not is_full(exc):
                raise
            return False
        self._checkpoint(db, "PASSIVE")
        self._count_drops(dropped, "disk")
        return dropped > 0

    def _recover_headroom(self) -> None:
        """After a full disk: take the headroom back, and the configured cap once the disk has room again."""
        if self.headroom.held or not self.headroom.take():
            return
        if self.headroom.disk_free() >= 2 * self.budget.headroom_bytes:
            self._cap_pages(self.budget.db_pages)

    def _cap_pages(self, pages: int) -> None:
        self._conn().execute(f"PRAGMA max_page_count={max(int(pages), 1)}")

    def _checkpoint(self, db: sqlite3.Connection, mode: str) -> None:
        try:
            db.execute(f"PRAGMA wal_checkpoint({mode})")
        except sqlite3.OperationalError as exc:
            if not is_full(exc):
                raise
            log.debug("spool checkpoint postponed: disk full")

    def _retry_acked(self, db: sqlite3.Connection) -> None:
        """Delete acknowledged rows in transactions of _DELETE_ROWS, each checkpointed, so the WAL stays small;
        on a full disk in smaller ones, then with the headroom freed, else keep the rest for the next call."""
        ids = sorted(self._acked)
        size, start = _DELETE_ROWS, 0
        while start < len(ids):
            chunk = ids[start:start + size]
            if not self._try_delete(db, chunk):
                if size > _FULL_DISK_DELETE_ROWS:
                    size = _FULL_DISK_DELETE_ROWS  # a full disk: what a small delete needs may still fit
                    continue
                if not (self.headroom.release() and self._try_delete(db, chunk)):
                    log.debug("acknowledged spool rows kept for a later delete: disk full rows=%d",
                              len(self._acked))
                    return
            start += len(chunk)
            self._checkpoint(db, "PASSIVE")

    def _try_delete(self, db: sqlite3.Connection, ids: list[int]) -> bool:
        """Delete the rows; False when the disk is too full for the delete to be written."""
        try:
            self._delete(db, ids)
        except sqlite3.OperationalError as exc:
            if not is_full(exc):
                raise
            return False
        return True

    def _delete(self, db: sqlite3.Connection, ids: list[int]) -> None:
        for start in range(0, len(ids), 500):
            chunk = ids[start:start + 500]
            listed = _listed(chunk)
            gone = db.execute(f"SELECT fmt, COUNT(*), COALESCE(SUM(size), 0) FROM spool WHERE id IN {_LISTED} "
                              f"GROUP BY fmt", (listed,)).fetchall()
            db.execute(f"DELETE FROM spool WHERE id IN {_LISTED}", (listed,))
            for fmt, count, size in gone:
                self._rows[str(fmt)] -= int(count)
                self.bytes -= int(size)
            for row_id in chunk:
                self._acked.pop(row_id, None)

    def _victims(self, db: sqlite3.Connection, rows: int) -> list[tuple[int, bytes]]:
        """Up to `rows` of the oldest rows (id, body) by the drop policy: data rows first, then events."""
        victims = db.execute("SELECT id, body FROM spool WHERE kind = 'data' ORDER BY id LIMIT ?",
                             (rows,)).fetchall()
        return victims or db.execute("SELECT id, body FROM spool ORDER BY id LIMIT ?", (rows,)).fetchall()

    def _lost_samples(self, rows: Sequence[tuple[int, bytes]]) -> int:
        """Samples in these rows that were never delivered (an acknowledged row is gone, but not lost).
        Ask before deleting them: the delete forgets the acknowledgement."""
        return sum(_sample_count(bytes(body)) for row_id, body in rows if row_id not in self._acked)

    def _drop_oldest(self, db: sqlite3.Connection, rows: int) -> int:
        """Delete up to `rows` of the oldest rows by the policy (data before events); samples dropped."""
        victims = self._victims(db, rows)
        if not victims:
            return 0
        lost = self._lost_samples(victims)
        self._delete(db, [r[0] for r in victims])
        return lost

    def _enforce_bounds(self, db: sqlite3.Connection) -> None:
        self._enforce_age(db)
        while self.bytes > self.max_bytes and sum(self._rows.values()) > 0:
            dropped = 0
            for victim in self._victims(db, 64):
                if self.bytes <= self.max_bytes:
                    break
                dropped += self._lost_samples([victim])
                self._delete(db, [victim[0]])
            self._count_drops(dropped, "size")
        if not sum(self._rows.values()):
            self._end_episode()

    def _enforce_age(self, db: sqlite3.Connection) -> None:
        """Drop the rows older than max_age_s. Runs at every commit and replay step, so it first asks the
        `created` index for the oldest row: the query below scans the whole table (ORDER BY id), 12 ms at
        60,000 rows, once per loop turn during a 1,000-machine outage."""
        cutoff = self._clock() - self.max_age_s
        oldest = db.execute("SELECT MIN(created) FROM spool").fetchone()[0]
        if oldest is None or oldest >= cutoff:
            return
        rows = db.execute("SELECT id, body FROM spool WHERE created < ? ORDER BY id", (cutoff,)).fetchall()
        if not rows:
            return
        lost = self._lost_samples(rows)
        self._delete(db, [r[0] for r in rows])
        self._count_drops(lost, "age")

    def _count_drops(self, samples: int, reason: str) -> None:
        """Count dropped samples; one WARNING when an episode of drops starts (it ends when the spool drains)."""
        if samples <= 0:
            return
        self.dropped += samples
        if self._episode_dropped is None:
            self._episode_dropped = 0
            log.warning("spool full, dropping the oldest samples until it drains reason=%s dropped_total=%d "
                        "max_bytes=%d max_age_s=%s path=%s", reason, self.dropped, self.max_bytes,
                        self.max_age_s, self.path)
        self._episode_dropped += samples

    def _end_episode(self) -> None:
        if self._episode_dropped is not None:
            log.warning("spool drained, the drop episode is over dropped_in_episode=%d dropped_total=%d",
                        self._episode_dropped, self.dropped)
            self._episode_dropped = None


_INSERT = "INSERT INTO spool (fmt, device, kind, created, size, body) VALUES (?, ?, ?, ?, ?, ?)"
# A list of ids or devices goes to SQLite as one JSON parameter, not a `?` each: every length of an
# `IN (?, ?, ...)` list is a statement of its own in the connection's cache of 128 prepared statements, and
# those of hundreds of parameters are ~100-200 kB each (1,000 machines: 21 MB of SQLite's heap before any
# outage, the replays' reads, acks and per-device queries). One text per query keeps a handful cached.
_LISTED = "(SELECT value FROM json_each(?))"


def _listed(values: Iterable[object]) -> str:
    return json.dumps(list(values), separators=(",", ":"))


# SQLite's page cache for the spool, at most (its default is 2 MB). Rows are appended at the end of the table
# and its indexes and replayed and deleted from the start: the pages in use are a few at each end, and a
# 60,000-row outage at 1,000 machines costs the same CPU with a quarter of the cache, which otherwise stays
# filled with the pages of rows long gone (the RSS step across an outage).
_CACHE_KIB = 512
_ROOM_ATTEMPTS = 8  # rounds of dropping before a row that still does not fit is dropped itself
_ROOM_ROWS = 16  # oldest rows dropped per round
# Acknowledged rows deleted per transaction (each checkpointed): a replay step acks ~0.1 s of rows, over a
# thousand at 1,000 machines; ~0.3 MB of WAL, well inside its limit, and one checkpoint instead of eight.
_DELETE_ROWS = 500
_FULL_DISK_DELETE_ROWS = _ROOM_ROWS * 4


def _sample_count(body: bytes) -> int:
    try:
        rows = json.loads(body)
    except ValueError:
        return 1
    return len(rows) if isinstance(rows, list) else 1


class UnopenedSpool:
    """Stands in when the spool file cannot be opened (a disk with no byte left at start): what cannot be
    published is counted as dropped, so the daemon runs and publishes live data; a restart retries."""

    def __init__(self, path: Path, error: Exception) -> None:
        self.path = path
        self.error = error
        self.dropped = 0
        self.held = 0
        self.depth = 0

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None:
        self.held += len(samples)
        self.dropped += len(samples)

    def pending(self, fmt: Format | None = None) -> int:
        return 0

    def oldest(self, fmt: Format, limit: int, devices: Collection[str] | None = None, *, lazy: bool = False,
               after: int = 0) -> list[SpoolEntry]:
        return []

    def ack(self, ids: Sequence[int]) -> None:
        return None

    def flush(self) -> None:
        return None

    def close(self) -> None:
        return None


def open_spool(state_dir: Path, max_bytes: int, max_age_s: float) -> DiskSpool | UnopenedSpool:
    """The daemon's spool: `spool.sqlite` in the state directory. A file that is not a database (or a
    malformed one) is moved aside, kept for inspection, and a new spool opened: otherwise every restart would
    meet the same file and the next broker outage would lose its samples. A spool that cannot be opened at
    all (no byte left on the disk) is one that counts what it cannot keep; both logged as an ERROR naming the
    file and the cause."""
    path = Path(state_dir) / FILE_NAME
    try:
        return DiskSpool(path, max_bytes=max_bytes, max_age_s=max_age_s)
    except sqlite3.DatabaseError as exc:
        if isinstance(exc, sqlite3.OperationalError):  # cannot open or write (full disk, permissions)
            return _unopened(path, exc)
        aside = _move_aside(path)
        log.error("spool file is corrupt (%s): moved to %s, its rows are not replayed; a new spool is started "
                  "path=%s", exc, aside, path)
        try:
            return DiskSpool(path, max_bytes=max_bytes, max_age_s=max_age_s)
        except (sqlite3.Error, OSError) as again:
            return _unopened(path, again)
    except OSError as exc:
        return _unopened(path, exc)


def _unopened(path: Path, exc: Exception) -> UnopenedSpool:
    log.error("spool cannot be opened, samples that cannot be published are dropped (counted) until a "
              "restart path=%s error=%s", path, exc)
    return UnopenedSpool(path, exc)


def _move_aside(path: Path) -> Path:
    """Renames the database and its WAL/shared-memory files to `<name>.corrupt-<UTC time>[-wal|-shm]`."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    aside = path.with_name(f"{path.name}.corrupt-{stamp}")
    for suffix in ("", "-wal", "-shm"):
        source = path.with_name(path.name + suffix)
        if source.exists():
            source.rename(aside.with_name(aside.name + suffix))
    return aside
