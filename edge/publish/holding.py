"""What cannot go out live goes to a spool: the interface the publisher writes to, and a writer that survives it.

The publisher never blocks or raises because the broker is away: samples it cannot publish (no connection,
no birth yet, a suspect connection) are *held* in a `Spool` (edge.publish.spool.DiskSpool in the daemon, a
counter by default). A spool that fails (a full or broken disk) costs the samples it could not take, counted
and logged once per episode, never the publisher.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence
from typing import Any, Literal, Protocol, runtime_checkable

from edge.publish.forwarding import HeldBatch
from edge.samples import Sample

log = logging.getLogger(__name__)

Format = Literal["sparkplug", "json"]
SampleKind = Literal["data", "events"]


class Spool(Protocol):
    """Receives what could not be published (broker away, no birth yet). A disk spool replays it later."""

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None: ...


@runtime_checkable
class ReplaySpool(Protocol):
    """A spool that can give its rows back for replay (edge.publish.spool.DiskSpool)."""

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None: ...

    def oldest(self, fmt: Format, limit: int, devices: Any = None, **kw: Any) -> Sequence[Any]: ...

    def ack(self, ids: Sequence[int]) -> None: ...

    def pending(self, fmt: Format | None = None) -> int: ...


@runtime_checkable
class IndexedSpool(Protocol):
    """A replay spool that also hands out a step's row ids by device, and reads their bodies in parts
    (edge.publish.spool.DiskSpool; the Sparkplug replay reads a step a few devices at a time)."""

    def oldest_ids(self, fmt: Format, limit: int, devices: Any = None, *, after: int = 0) -> dict[str, list[int]]: ...

    def read(self, fmt: Format, ids: Sequence[int]) -> Sequence[Any]: ...


class DroppingSpool:
    """The default spool: counts what is lost."""

    def __init__(self) -> None:
        self.dropped = 0

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None:
        self.dropped += len(samples)


class SpoolWriter:
    """Hands held batches to the spool, for both formats; counts what a failing spool lost."""

    def __init__(self, spool: Spool, counters: Counter[str]) -> None:
        self.spool = spool
        self._counters = counters
        self._failing = False  # a spool write failed and no write has worked since (log once)

    def write(self, fmt: Format, batch: HeldBatch) -> None:
        kind: SampleKind = "events" if batch.kind == "events" else "data"
        try:
            self.spool.hold(fmt, batch.device_id, kind, batch.samples)
        except Exception as exc:  # a broken spool must not take the publisher down
            self._counters["spool_errors"] += 1
            self._counters["spool_error_samples"] += len(batch.samples)
            if not self._failing:
                log.error("spool write failed, samples lost until a write works again (counted in "
                          "spool_error_samples) format=%s device=%s samples=%d error=%s", fmt,
                          batch.device_id, len(batch.samples), exc)
            self._failing = True
            return
        if self._failing:
            log.warning("spool writes work again, lost samples=%d", self._counters["spool_error_samples"])
        self._failing = False
        self._counters["spooled_batches"] += 1
