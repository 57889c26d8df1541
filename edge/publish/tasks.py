"""The one owner of the publisher's background tasks (subscriptions, probes, replays, command handlers).

Every task the publishing side starts is spawned here, so `stop()` can cancel and await all of them, and a
task that fails is logged instead of vanishing. `stopping` is the publisher's shutdown flag: the sessions and
the replays read it to start nothing new once a stop began.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Coroutine
from typing import Any

log = logging.getLogger(__name__)


class BackgroundTasks:
    """The running tasks of one publisher, and whether it is stopping."""

    def __init__(self) -> None:
        self._tasks: set[asyncio.Task[None]] = set()
        self.stopping = False

    def spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._task_done)

    async def cancel_all(self) -> None:
        """Cancel every running task and wait until each has ended."""
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)

    def _task_done(self, task: asyncio.Task[None]) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            log.error("publisher task failed", exc_info=task.exception())


async def awaited(awaitable: Awaitable[None]) -> None:
    """An awaitable (a command handler's result) as a coroutine `spawn` accepts."""
    await awaitable
