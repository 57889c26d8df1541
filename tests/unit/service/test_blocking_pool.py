"""The daemon's blocking calls run in a named pool whose size is bounded, so thread counts can be read."""

from __future__ import annotations

import asyncio
import threading

from edge.service.blocking_pool import BLOCKING_WORKERS, THREAD_PREFIX, blocking_pool_threads, install_blocking_pool


async def test_blocking_calls_run_in_named_threads() -> None:
    install_blocking_pool(asyncio.get_running_loop())
    name = await asyncio.to_thread(lambda: threading.current_thread().name)
    assert name.startswith(THREAD_PREFIX)
    assert blocking_pool_threads() >= 1


async def test_overlapping_calls_never_start_more_workers_than_the_bound() -> None:
    install_blocking_pool(asyncio.get_running_loop())
    release, threads = threading.Event(), set()

    def hold() -> bool:
        threads.add(threading.get_ident())
        return release.wait(10)

    calls = asyncio.gather(*(asyncio.to_thread(hold) for _ in range(BLOCKING_WORKERS * 3)))
    await asyncio.sleep(0)  # every call is submitted to the pool now; the first BLOCKING_WORKERS hold it
    release.set()
    assert all(await calls)
    assert len(threads) <= BLOCKING_WORKERS, f"{len(threads)} threads served overlapping blocking calls"


async def test_installing_twice_on_one_loop_keeps_the_first_pool() -> None:
    loop = asyncio.get_running_loop()
    assert install_blocking_pool(loop) is install_blocking_pool(loop)
