"""How the spool's files fit in `max_bytes` and survive a full disk: the budget, the headroom file, SQLITE_FULL.

SQLite in WAL mode writes whole pages: one 260-byte row costs ~4 pages (table, two indexes, the sequence)
in the WAL, and the WAL only shrinks at a checkpoint. Left alone it grows to ~4 MB before the automatic
checkpoint, so the bound on the spool's *payload* said little about its *disk use*. The budget splits
`max_bytes` into
- the database: a page cap (PRAGMA max_page_count) -- a row beyond it fails with SQLITE_FULL, which the
  spool answers by dropping the oldest rows (freed pages are reused, so the file stops growing);
- the WAL: checkpointed every `wal_checkpoint_pages` pages and cut back to `wal_bytes` after each
  checkpoint (journal_size_limit);
- the headroom: a file of `headroom_bytes` kept beside the database and deleted when the disk is full, so
  that a DELETE (which needs WAL space) and the checkpoint after it can still be written.
"""

from __future__ import annotations

import logging
import os
import sqlite3
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

WAL_FRAME_HEADER = 24
MIN_WAL_PAGES = 16
MAX_WAL_BYTES = 4 * 1024 * 1024


@dataclass(frozen=True, slots=True)
class DiskBudget:
    """Where `max_bytes` goes: database pages, WAL, headroom (all of it on disk at most)."""

    db_pages: int  # PRAGMA max_page_count
    wal_bytes: int  # PRAGMA journal_size_limit: the WAL's size after a checkpoint
    wal_checkpoint_pages: int  # PRAGMA wal_autocheckpoint: leaves room for one transaction in wal_bytes
    headroom_bytes: int  # the file given up when the disk is full


def disk_budget(max_bytes: int, page_size: int, disk_bytes: int | None = None) -> DiskBudget:
    """An eighth of `max_bytes` for the WAL (16 pages to 4 MiB), as much for the headroom, the rest for pages.

    The WAL and the headroom are sized to the smaller of `max_bytes` and the filesystem (`disk_bytes`): a
    256 MiB bound on a 1 MiB disk still gets a WAL that is checkpointed long before the disk is full.
    """
    frame = page_size + WAL_FRAME_HEADER
    room = max_bytes if disk_bytes is None else min(max_bytes, disk_bytes)
    wal_bytes = min(max(room // 8, MIN_WAL_PAGES * frame), MAX_WAL_BYTES)
    headroom = wal_bytes
    db_pages = max((max_bytes - wal_bytes - headroom) // page_size, 16)
    return DiskBudget(db_pages, wal_bytes, max(wal_bytes // frame // 2, 1), headroom)


def filesystem_bytes(directory: Path) -> int:
    """The size of the filesystem holding `directory`."""
    stat = os.statvfs(directory)
    return stat.f_blocks * stat.f_frsize


def is_full(exc: sqlite3.Error) -> bool:
    """SQLITE_FULL: the page cap was reached or the disk is full (SQLite says the same for both)."""
    return getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL or "is full" in str(exc)


class Headroom:
    """A file of reserved bytes beside the spool, given back to the filesystem when it is full."""

    def __init__(self, path: Path, size: int) -> None:
        self.path = path
        self.size = size
        self.held = False

    def take(self) -> bool:
        """Reserve the bytes (written, not sparse); False on a disk too full to hold them.

        The spool asks again after every write while the bytes are given back: on a disk with less free
        than `size` it is told no at the cost of a statvfs, not of writing the free bytes and deleting them.
        """
        if self.disk_free() < self.size:
            self.held = False
            return False
        try:
            with self.path.open("wb") as handle:
                handle.write(b"\0" * self.size)
                handle.flush()
                os.fsync(handle.fileno())
        except OSError:
            self.path.unlink(missing_ok=True)
            self.held = False
            return False
        self.held = True
        return True

    def release(self) -> bool:
        """Give the bytes back; False when there were none to give."""
        if not self.held:
            return False
        self.path.unlink(missing_ok=True)
        self.held = False
        log.debug("spool headroom released path=%s bytes=%d", self.path, self.size)
        return True

    def disk_free(self) -> int:
        stat = os.statvfs(self.path.parent)
        return stat.f_bavail * stat.f_frsize
