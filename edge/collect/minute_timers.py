"""The utilisation minute of every machine on one timer: a due-time heap instead of a sleeping task per machine.

Each machine publishes its utilisation counters once a minute (and at local midnight) and saves them every
SAVE_EVERY_MINUTES (edge.collect.plant_state). A task per machine asleep between minutes held ~1 kB (the
task, its coroutine frames, the sleep's future and timer) for 59 s of every 60: 1 MB at 1,000 machines. Here
a machine waiting for its minute is one small entry in a heap, one loop timer is armed for the earliest, and a
task is made only for the minute's own work (count, publish, perhaps save), which awaits the publisher.

The delays are the ones the sleeping task took (PlantState.next_delay_s, asked after the previous minute's
work) and the timer fires as the loop would have woken the sleep, so what is published and when is unchanged.
"""

from __future__ import annotations

import asyncio
import heapq
import logging
import time
from collections.abc import Awaitable, Callable, Sequence

from edge.collect.plant_state import SAVE_EVERY_MINUTES, PlantState
from edge.samples import Sample

log = logging.getLogger(__name__)

Publish = Callable[[Sequence[Sample]], Awaitable[None]]


class MinuteRound:
    """One machine's minutes on the shared timer; `cancel()` ends them (its poller's run ends)."""

    __slots__ = ("_timers", "cancelled", "minutes", "now_ms", "publish", "state", "task", "wall")

    def __init__(self, timers: MinuteTimers, state: PlantState, now_ms: Callable[[], int], publish: Publish,
                 wall: Callable[[], float]) -> None:
        self._timers = timers
        self.state = state
        self.now_ms = now_ms
        self.publish = publish
        self.wall = wall
        self.minutes = 0
        self.cancelled = False
        self.task: asyncio.Task[None] | None = None  # the minute's work while it runs

    def cancel(self) -> None:
        self.cancelled = True  # its heap entry is skipped when due
        if self.task is not None:
            self.task.cancel()

    def _due_in(self) -> float:
        return self.state.next_delay_s(self.wall(), self.now_ms())

    async def _minute(self) -> None:
        """Count, publish; every SAVE_EVERY_MINUTES, save; then wait for the next minute."""
        state = self.state
        await self.publish(state.minute(self.now_ms()))
        self.minutes += 1
        if not self.minutes % SAVE_EVERY_MINUTES:
            try:
                await state.save_in_thread()
            except OSError as exc:
                log.warning("utilisation not saved machine=%s file=%s error=%s", state.device_id,
                            state.store.path, exc)
        self.task = None
        self._timers.wait(self, self._due_in())


class MinuteTimers:
    """The machines' minutes on one event loop (`for_loop`): one armed timer, for the earliest one due."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._heap: list[tuple[float, int, MinuteRound]] = []
        self._seq = 0  # ties in the heap go in the order they were added
        self._handle: asyncio.TimerHandle | None = None
        self._armed_at = float("inf")

    def start(self, state: PlantState, now_ms: Callable[[], int], publish: Publish,
              wall: Callable[[], float] = time.time) -> MinuteRound:
        """The machine's first minute, from now on."""
        entry = MinuteRound(self, state, now_ms, publish, wall)
        self.wait(entry, entry._due_in())
        return entry

    def wait(self, entry: MinuteRound, delay_s: float) -> None:
        if entry.cancelled:
            return
        when = self._loop.time() + delay_s  # as asyncio.sleep's call_later
        self._seq += 1
        heapq.heappush(self._heap, (when, self._seq, entry))
        if when < self._armed_at:
            self._arm(when)

    def _arm(self, when: float) -> None:
        if self._handle is not None:
            self._handle.cancel()
        self._armed_at = when
        self._handle = self._loop.call_at(when, self._fire)

    def _fire(self) -> None:
        """Start the minute of every machine due (by the loop's rule for timers: within its clock resolution)."""
        self._handle, self._armed_at = None, float("inf")
        heap, loop = self._heap, self._loop
        end = loop.time() + getattr(loop, "_clock_resolution", 0.0)  # BaseEventLoop's rule for a timer due
        while heap and heap[0][0] <= end:
            entry = heapq.heappop(heap)[2]
            if not entry.cancelled:
                entry.task = loop.create_task(entry._minute())
        if heap:
            self._arm(heap[0][0])

    @classmethod
    def for_loop(cls, loop: asyncio.AbstractEventLoop | None = None) -> MinuteTimers:
        """The timers of this event loop: one set, made when first asked. Only the last loop's set is kept here
        (a daemon has one loop; a test suite makes many, and a set refers to its loop); a machine's minutes stay
        on the set they started on whatever is asked later."""
        global _CURRENT
        loop = loop or asyncio.get_running_loop()
        if _CURRENT is None or _CURRENT._loop is not loop:
            _CURRENT = cls(loop)
        return _CURRENT


_CURRENT: MinuteTimers | None = None
