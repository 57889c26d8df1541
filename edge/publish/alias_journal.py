"""The alias map's journal: aliases assigned since the document was last written, one JSON line a save.

Appending costs what is new, not the whole map. A line is written and flushed at once (a crash of the
process loses nothing); the data is synced to disk at most once per SYNC_INTERVAL_S, since a fleet's first
start saves once per device and each sync takes milliseconds of the event loop (power lost within that
interval can forget the newest aliases: the next births declare them again, under new numbers). A torn
last line, the one a power loss can leave, is skipped when the journal is read.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import time
from pathlib import Path

log = logging.getLogger(__name__)

SYNC_INTERVAL_S = 1.0


class AliasJournal:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._synced_at = -SYNC_INTERVAL_S
        self._sync_pending: asyncio.TimerHandle | None = None

    def read(self) -> list[tuple[str, dict[str, object]]]:
        """Every complete line as (device, {name: alias}); nothing if there is no journal."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return []
        entries: list[tuple[str, dict[str, object]]] = []
        for number, line in enumerate(text.splitlines(), 1):
            try:
                device, names = json.loads(line)
            except (ValueError, TypeError):
                log.warning("alias journal line skipped (torn or not a [device, names] pair) path=%s line=%d",
                            self.path, number)
                continue
            if isinstance(device, str) and isinstance(names, dict):
                entries.append((device, names))
        return entries

    def append(self, devices: dict[str, dict[str, int]]) -> None:
        """One line per device; flushed now, synced now or within SYNC_INTERVAL_S."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = "".join(json.dumps([device, names], separators=(",", ":")) + "\n" for device, names in devices.items())
        with self.path.open("a", encoding="utf-8") as handle:
            handle.write(data)
            handle.flush()
            if time.monotonic() - self._synced_at >= SYNC_INTERVAL_S or not self._defer_sync():
                self._sync(handle.fileno())

    def _defer_sync(self) -> bool:
        """Arrange one sync at the end of the interval; False when there is no event loop to do it."""
        if self._sync_pending is not None:
            return True
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return False
        delay = SYNC_INTERVAL_S - (time.monotonic() - self._synced_at)
        self._sync_pending = loop.call_later(max(0.0, delay), self._sync_later)
        return True

    def _sync_later(self) -> None:
        self._sync_pending = None
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError as exc:
            log.warning("alias journal not synced error=%s", exc)
            return
        try:
            self._sync(fd)
        finally:
            os.close(fd)

    def _sync(self, fd: int) -> None:
        try:
            os.fdatasync(fd)
        except OSError as exc:
            log.warning("alias journal not synced error=%s", exc)
        self._synced_at = time.monotonic()

    def clear(self) -> None:
        """The journal folded into the document: start afresh."""
        if self._sync_pending is not None:
            self._sync_pending.cancel()
            self._sync_pending = None
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
