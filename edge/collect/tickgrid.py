"""Poll wake-ups quantised to a shared time grid.

Every machine waking on its own timer costs the event loop one timer and one turn (one epoll wait) per
tick: at 100 machines x 10 Hz that is a thousand turns a second, most of them for a single machine.
Rounding each wake-up up to the next grid point (the config's `poll_grid_s`, 25 ms by default) lets the
machines due in the same slot share one timer and one loop turn, while a fleet still spreads over the
slots of a period (their start phases are jittered), so the CNCs and the broker never see the whole fleet
in lock-step. A coarser grid is cheaper per machine-cycle and adds latency (docs/performance.md).

A wake-up is never early: at most one grid step late, and the schedule keeps its own phase (the next due
time is computed from the due time, not from the wake-up), so a machine stays in its slot.
"""

from __future__ import annotations

import asyncio
import math

from edge.config import DEFAULT_POLL_GRID_S


class TickGrid:
    """Shared by the pollers of one event loop: `await grid.sleep_until(monotonic_deadline)`."""

    def __init__(self, step_s: float = DEFAULT_POLL_GRID_S) -> None:
        if not step_s > 0:
            raise ValueError(f"tick grid step must be > 0 s, got {step_s}")
        self.step_s = step_s
        self._slots: dict[int, list[asyncio.Future[None]]] = {}

    def slot_time(self, when: float) -> float:
        """The grid point a wake-up for `when` (loop/monotonic seconds) happens at."""
        return math.ceil(when / self.step_s) * self.step_s

    async def sleep_until(self, when: float) -> None:
        """Sleep until the grid point at or after `when`; cancelling one sleeper affects no other."""
        loop = asyncio.get_running_loop()
        slot = math.ceil(when / self.step_s)
        if slot * self.step_s <= loop.time():
            await asyncio.sleep(0)  # already due: yield once, as asyncio.sleep(0) would
            return
        waiters = self._slots.get(slot)
        if waiters is None:
            waiters = self._slots[slot] = []
            loop.call_at(slot * self.step_s, self._fire, slot)
        waiter: asyncio.Future[None] = loop.create_future()
        waiters.append(waiter)
        await waiter

    def _fire(self, slot: int) -> None:
        for waiter in self._slots.pop(slot, ()):
            if not waiter.done():
                waiter.set_result(None)

    @property
    def pending_slots(self) -> int:
        """Slots with a timer armed (for tests: it must not grow)."""
        return len(self._slots)
