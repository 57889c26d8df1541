"""Garbage-collector settings for the long-running daemon.

Every poll tick allocates and frees small objects (samples, answer tuples, lists); reference counting frees
almost all of them. With CPython's default young-generation threshold (700) the cyclic collector still
ran ~20 young collections a second at 100 machines and a full one every few seconds over the ~100k
long-lived objects of the process (modules, configuration, plans, metric tables): 5-8 % of the gateway's
CPU in `python -m bench fleet`. So the objects alive after start-up are frozen out of the collector and
the young threshold is raised. Cyclic garbage (rare here) is still collected, only less often.

Start-up's freeze comes before the machines exist, though. Each machine's session then builds its plans,
prepared batches, answer memos and encoder tables (~1,000 tracked objects a machine): at 1,000 machines
1.1-1.3 M objects the collector's full collections walked, each holding the event loop 120-175 ms (and more
on a loaded host), the largest part of the sample latency's p99 there (docs/performance.md, "Latency at
1,000 machines"). `CollectorKeeper` freezes those too once the machines are born (at start-up and after
each reload), and now and then unfreezes everything for one full collection: a frozen object is never
examined for cycles, so a dropped session whose objects were frozen would otherwise never be freed.

The keeper also runs the young collections by the clock. CPython triggers a young collection when
allocations minus deallocations of tracked objects pass the threshold, and any tracked object's
deallocation counts, an old one's too. In a steady fleet each tick frees about as many (older) objects as
it makes, so the count hovers near zero while the young generation keeps every object the ticks keep (the
answers, samples and memo entries that replace last tick's): at 1,000 machines it held ~500 k objects when
something finally tipped it, one young collection holding the loop 0.5 s (`python -m bench.paced_replay`).
Collected every 0.1 s, it holds what 0.1 s of ticks kept. What survives that (objects the ticks keep for
a period or more) is frozen every second instead of going through middle and full collections: a middle
collection walks every such object of the whole fleet (~100-150 ms at 1,000 machines in `bench fleet
--diagnose`), while a freeze is a list splice. The young collections find no cyclic garbage in a steady
fleet (`gc_collected` 0 over a 40 s window at 1,000 machines); whatever a frozen cycle holds is freed by
the hourly full collection.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import time
from collections.abc import Callable

from edge.service import heap_trim

log = logging.getLogger(__name__)

YOUNG_THRESHOLD = 20_000  # allocations (net) between young collections; CPython's default is 700
SETTLE_CHECK_S = 1.0  # how often the keeper looks whether the machines started are born
SETTLE_LIMIT_S = 120.0  # a machine that never answers must not keep the others' objects in the collector
RECYCLE_PERIOD_S = 3600.0  # one full collection over everything (frozen too) this often: cycles are freed
YOUNG_PACE_S = 0.1  # a young collection this often, whatever the allocation count says (see above)
FREEZE_EVERY = 10  # and after every 10th, the survivors frozen (instead of middle and full collections)


def tune_collector() -> tuple[int, int, int]:
    """Freeze what start-up built and raise the young threshold; returns the previous thresholds."""
    previous = gc.get_threshold()
    gc.collect()  # start-up's own garbage first, so it is not frozen
    gc.freeze()
    gc.set_threshold(YOUNG_THRESHOLD, previous[1], previous[2])
    return previous


def settle(recycle: bool = False) -> tuple[int, float]:
    """Collect, then freeze what survived: (objects frozen in all, seconds the loop was held).

    `recycle` unfreezes first, so the collection examines every object (and frees frozen cycles). Start-up's
    and a reload's garbage is gone then, so the C heap's free pages go back to the system too."""
    started = time.perf_counter()
    if recycle:
        gc.unfreeze()
    gc.collect()
    gc.freeze()
    heap_trim.trim()
    return gc.get_freeze_count(), time.perf_counter() - started


class CollectorKeeper:
    """Freezes the machines' long-lived objects once the machines started are born; recycles hourly; runs
    the young collections by the clock and freezes their survivors every second.

    `born` says whether every machine started so far is online (DBIRTH sent). The daemon calls
    `machines_started()` after start-up's and each reload's starts; `run()` is its background task.
    """

    def __init__(self, born: Callable[[], bool], clock: Callable[[], float] = time.monotonic,
                 check_s: float = SETTLE_CHECK_S, limit_s: float = SETTLE_LIMIT_S,
                 recycle_s: float = RECYCLE_PERIOD_S, pace_s: float = YOUNG_PACE_S) -> None:
        self._born = born
        self._clock = clock
        self._check_s = check_s
        self._pace_s = pace_s
        self._limit_s = limit_s
        self._recycle_s = recycle_s
        self._started_at: float | None = None  # machines started and not yet settled since
        self._recycled_at = clock()
        self.settled = 0  # settles done (for tests and the log)

    def machines_started(self) -> None:
        if self._started_at is None:
            self._started_at = self._clock()

    def step(self) -> bool:
        """Settle or recycle when it is time: True when it did (one collection, the loop held meanwhile)."""
        now = self._clock()
        if now - self._recycled_at >= self._recycle_s:
            self._recycled_at = now
            self._started_at = None
            self._log("recycled", *settle(recycle=True))
            return True
        if self._started_at is not None and (self._born() or now - self._started_at >= self._limit_s):
            self._started_at = None
            self._log("settled", *settle())
            return True
        return False

    def _log(self, what: str, frozen: int, held_s: float) -> None:
        self.settled += 1
        log.info("collector %s: %d objects frozen, loop held %.0f ms", what, frozen, held_s * 1000)

    async def run(self) -> None:
        """A young collection every `pace_s`, the survivors frozen every FREEZE_EVERY-th; `step()` every
        `check_s`."""
        paced = 0
        checked = self._clock()
        while True:
            await asyncio.sleep(self._pace_s)
            paced += 1
            gc.collect(0)
            if paced % FREEZE_EVERY == 0:
                gc.freeze()
            if self._clock() - checked >= self._check_s:
                checked = self._clock()
                self.step()
