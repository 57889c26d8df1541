"""Poll wake-ups quantised to a shared time grid.

Every machine waking on its own timer costs the event loop one timer and one turn (one epoll wait) per
tick: at 100 machines x 10 Hz that is a thousand turns a second, most of them for a single machine.
Rounding each wake-up up to the next grid point (the config's `poll_grid_s`: by default half the fleet's
fastest poll period, at most 50 ms) lets the
machines due in the same slot share one timer and one loop turn, while a fleet still spreads over the
slots of a period (their start phases are jittered), so the CNCs and the broker never see the whole fleet
in lock-step. A coarser grid is cheaper per machine-cycle and adds latency (docs/performance.md).

A wake-up is never early: at most one grid step late, and the schedule keeps its own phase (the next due
time is computed from the due time, not from the wake-up), so a machine stays in its slot.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable

# Half the shortest poll period the config accepts (edge.config.SHORTEST_PERIOD_S; a unit test keeps the two
# together): a grid that fits any machine, for a poller given none.
DEFAULT_STEP_S = 0.025


class TickGrid:
    """Shared by the pollers of one event loop: `await grid.sleep_until(monotonic_deadline)`.

    The step may change while pollers sleep (a reload): a sleeper keeps the slot it was given, the next
    sleep uses the new step.
    """

    def __init__(self, step_s: float = DEFAULT_STEP_S) -> None:
        self._step_s = self._checked(step_s)
        self._slots: dict[tuple[float, int], list[asyncio.Future[None]]] = {}

    @staticmethod
    def _checked(step_s: float) -> float:
        if not step_s > 0:
            raise ValueError(f"tick grid step must be > 0 s, got {step_s}")
        return step_s

    @property
    def step_s(self) -> float:
        return self._step_s

    @step_s.setter
    def step_s(self, value: float) -> None:
        self._step_s = self._checked(value)

    def slot_time(self, when: float) -> float:
        """The grid point a wake-up for `when` (loop/monotonic seconds) happens at."""
        return math.ceil(when / self.step_s) * self.step_s

    async def sleep_until(self, when: float) -> None:
        """Sleep until the grid point at or after `when`; cancelling one sleeper affects no other."""
        await self.wake_at(when)

    def wake_at(self, when: float) -> Awaitable[None]:
        """sleep_until's awaitable, without a coroutine of its own (a poller awaits one every tick; each level
        of its await chain is re-entered at the wake-up): the slot's future, or one yield when already due."""
        loop = asyncio.get_running_loop()
        step = self._step_s
        index = math.ceil(when / step)
        if index * step <= loop.time():
            return asyncio.sleep(0)  # already due: yield once
        slot = (step, index)
        waiters = self._slots.get(slot)
        if waiters is None:
            waiters = self._slots[slot] = []
            loop.call_at(index * step, self._fire, slot)
        waiter: asyncio.Future[None] = loop.create_future()
        waiters.append(waiter)
        return waiter

    def _fire(self, slot: tuple[float, int]) -> None:
        for waiter in self._slots.pop(slot, ()):
            if not waiter.done():
                waiter.set_result(None)

    @property
    def pending_slots(self) -> int:
        """Slots with a timer armed (for tests: it must not grow)."""
        return len(self._slots)
