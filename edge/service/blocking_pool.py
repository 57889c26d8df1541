"""The daemon's own pool for its few blocking calls: the broker connect, plant-state saves, config reloads.

asyncio's default pool has no thread names and starts workers lazily up to min(32, CPUs + 4), one more each
time two blocking calls overlap; a soak that counts threads cannot tell that growth from a leak, and an
operator reading `top -H` cannot tell whose threads they are. This pool is named and its bound is stated.
"""

from __future__ import annotations

import asyncio
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor

BLOCKING_WORKERS = 4  # blocking calls that may overlap: a broker connect per connection, a save, a reload
THREAD_PREFIX = "edge-blocking"

_pools: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, ThreadPoolExecutor] = weakref.WeakKeyDictionary()


def install_blocking_pool(loop: asyncio.AbstractEventLoop) -> ThreadPoolExecutor:
    """Make the named pool the loop's default executor (run_in_executor(None, ...) and asyncio.to_thread).

    Once per loop: a second daemon run in the same loop (tests, reloads) keeps the pool and its workers."""
    pool = _pools.get(loop)
    if pool is None:
        pool = _pools[loop] = ThreadPoolExecutor(max_workers=BLOCKING_WORKERS, thread_name_prefix=THREAD_PREFIX)
        loop.set_default_executor(pool)
    return pool


def blocking_pool_threads() -> int:
    """How many of the pool's workers exist now (they stay once started, up to BLOCKING_WORKERS)."""
    return sum(1 for thread in threading.enumerate() if thread.name.startswith(THREAD_PREFIX))
