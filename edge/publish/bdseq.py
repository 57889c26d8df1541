"""The Sparkplug birth/death sequence number (bdSeq): +1 on every CONNECT, kept in memory, persisted best-effort.

Hosts pair an NDEATH with its NBIRTH by bdSeq, and the TCK expects each CONNECT to carry the previous one's
value + 1 even across daemon restarts, so the value is written to disk (atomically) before the CONNECT that
uses it goes out. The number in memory is the truth while the process runs: a write that fails (a full
disk) is a warning and a counted `persist_failures`, never a reason to stay offline. The cost of a failed
write shows only after a restart, which may reuse a number a host has seen (it then pairs by the NBIRTH).
An attempt that never got as far as sending CONNECT (socket refused) does not consume a number: the next
attempt reuses it.
"""

from __future__ import annotations

import logging
import threading

from edge.publish.state_store import StateStore

log = logging.getLogger(__name__)

DOCUMENT = "sparkplug_bdseq"


class BdSeqCounter:
    """Hands out bdSeq values 0..255 (wrapping), one per CONNECT; safe to call from paho's thread."""

    def __init__(self, store: StateStore | None = None) -> None:
        self._store = store
        self._lock = threading.Lock()
        self._last: int | None = None  # the value carried by the last CONNECT (or reserved for it)
        self._current: int | None = None
        self.persist_failures = 0  # writes of the value that failed (the value was used anyway)
        if store is not None:
            doc = store.load(DOCUMENT)
            value = doc.get("last") if doc else None
            if isinstance(value, int) and 0 <= value <= 255:
                self._last = value

    @property
    def last(self) -> int | None:
        """The value of the last CONNECT, this run's or (loaded from the store) the previous run's."""
        with self._lock:
            return self._last

    @property
    def current(self) -> int | None:
        """The value of the most recent CONNECT attempt (what the Will and the NBIRTH carry)."""
        with self._lock:
            return self._current

    def next_for_connect(self, previous_unsent: bool = False) -> int:
        """The bdSeq for the CONNECT about to be sent, persisted first when the disk allows.

        `previous_unsent`: the previous attempt failed before its CONNECT left, so its number is reused.
        """
        with self._lock:
            if previous_unsent and self._current is not None:
                return self._current
            value = 0 if self._last is None else (self._last + 1) % 256
            self._last = value
            self._current = value
            self._persist(value)
            return value

    def _persist(self, value: int) -> None:
        if self._store is None:
            return
        try:
            self._store.save(DOCUMENT, {"last": value})
        except OSError as exc:
            self.persist_failures += 1
            log.warning("bdSeq not persisted, connecting with it anyway bdseq=%d failures=%d error=%s",
                        value, self.persist_failures, exc)
