"""Request deadlines on a coarse grid shared by every session of an event loop.

`asyncio.timeout` arms one TimerHandle per request: built in Python, pushed on the loop's heap (Python
comparisons) and later dropped from it. A fleet's pollers do that ten times a second per machine for a
timeout of seconds that almost never fires. Here each request arms a `Deadline` into a slot of the
wheel instead: the deadline is rounded UP to the grid (never early, at most one step late), every
deadline in a slot shares that slot's single timer, and the timer cancels the tasks still registered
when it fires. Disarming is a set removal.

The cancellation is turned into TimeoutError the way asyncio.timeout does it: only when the wheel
cancelled the task and nobody else asked for a cancellation meanwhile (`Task.uncancel()`).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import weakref
from collections.abc import Callable

DEFAULT_STEP_S = 0.05


class Deadline:
    """One request's registration: armed before it is sent, disarmed when it ends."""

    __slots__ = ("_slot", "_task", "expired")

    def __init__(self) -> None:
        self._task: asyncio.Task[object] | None = None
        self._slot: int | None = None
        self.expired = False  # the wheel cancelled the task for this arming


class DeadlineWheel:
    """The deadlines of one event loop, by grid slot; one armed timer per slot that holds any."""

    def __init__(self, loop: asyncio.AbstractEventLoop, step_s: float = DEFAULT_STEP_S) -> None:
        if not step_s > 0:
            raise ValueError(f"deadline grid step must be > 0 s, got {step_s}")
        self.step_s = step_s
        # Weak: the module's registry is keyed weakly by the loop (a loop without weak references is
        # held strongly, and its callers get wheels of their own).
        self._loop: Callable[[], asyncio.AbstractEventLoop | None]
        try:
            self._loop = weakref.ref(loop)
        except TypeError:
            self._loop = lambda: loop
        self._slots: dict[int, set[Deadline]] = {}

    def arm(self, deadline: Deadline, task: asyncio.Task[object], timeout_s: float) -> None:
        """Cancel `task` at the first grid point at or after now + timeout_s unless disarmed first."""
        if deadline._slot is not None:
            raise RuntimeError("deadline is already armed")
        loop = self._loop()
        if loop is None:
            raise RuntimeError("the deadline wheel's event loop is gone")
        slot = math.ceil((loop.time() + timeout_s) / self.step_s)
        members = self._slots.get(slot)
        if members is None:
            members = self._slots[slot] = set()
            loop.call_at(slot * self.step_s, self._fire, slot)
        members.add(deadline)
        deadline._task, deadline._slot, deadline.expired = task, slot, False

    def serves(self, loop: asyncio.AbstractEventLoop) -> bool:
        return self._loop() is loop

    def disarm(self, deadline: Deadline) -> None:
        slot, deadline._slot, deadline._task = deadline._slot, None, None
        if slot is not None:
            members = self._slots.get(slot)
            if members is not None:
                members.discard(deadline)

    def _fire(self, slot: int) -> None:
        for deadline in self._slots.pop(slot, ()):
            task = deadline._task
            deadline._slot, deadline._task = None, None
            if task is not None and not task.done():
                deadline.expired = True
                task.cancel()

    @property
    def pending_slots(self) -> int:
        """Slots with a timer armed (for tests: bounded by timeout / step, not by the request count)."""
        return len(self._slots)


_WHEELS: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, DeadlineWheel] = weakref.WeakKeyDictionary()


def wheel_for(loop: asyncio.AbstractEventLoop) -> DeadlineWheel:
    """The loop's shared wheel (created on first use, gone with the loop)."""
    wheel = _WHEELS.get(loop)
    if wheel is None:
        wheel = DeadlineWheel(loop)
        with contextlib.suppress(TypeError):  # a loop without weak references: a wheel of this caller's own
            _WHEELS[loop] = wheel
    return wheel
