"""No leaks: after 50 CNC connect/drop cycles (and MQTT drops among them) the daemon's open file
descriptors, asyncio tasks and threads are back to their starting counts."""

from __future__ import annotations

import asyncio
import gc
import json
import os
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

CYCLES = 50
MQTT_EVERY = 10  # every 10th cycle also drops both MQTT connections


def counts() -> dict[str, int]:
    gc.collect()  # unreferenced file objects (of earlier tests too) close now, not at a random later point
    return {"fds": len(os.listdir("/proc/self/fd")), "tasks": len(asyncio.all_tasks()),
            "threads": threading.active_count()}


async def settled() -> dict[str, int]:
    """Counts once they hold still for 1.5 s (old probe loops end within a probe interval)."""
    last, stable_since = counts(), asyncio.get_running_loop().time()
    deadline = stable_since + 15
    while asyncio.get_running_loop().time() < deadline:
        await asyncio.sleep(0.1)
        now = counts()
        if now != last:
            last, stable_since = now, asyncio.get_running_loop().time()
        elif asyncio.get_running_loop().time() - stable_since >= 1.5:
            break
    return last


@pytest.fixture
async def observer(mosquitto: Mosquitto) -> AsyncIterator[Observer]:
    obs = Observer(mosquitto, topics=("spBv1.0/#",))
    yield obs
    obs.close()


async def test_fds_tasks_threads_return_to_start_after_50_drop_cycles(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        text = f"""
mqtt: {{host: {mosquitto.host}, port: {mosquitto.port}, formats: [sparkplug, json],
        sparkplug: {{group_id: plant, edge_node_id: gw}}}}
state_dir: {tmp_path}
machines:
  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, poll: {{periods: {{status: 0.1s}}}},
     timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.05, backoff_max_s: 0.2}}}}
"""
        daemon = Daemon(parse_config(text))
        daemon.publisher.settings.reconnect_min_s = 0.05
        daemon.publisher.settings.reconnect_max_s = 0.2
        task = asyncio.create_task(daemon.run())
        births = 0

        async def cycle(n: int) -> None:
            nonlocal births
            if n % MQTT_EVERY == 0:
                nbirths = len(observer.of("NBIRTH"))
                daemon.publisher.drop_connections()
                await async_wait_for(lambda: len(observer.of("NBIRTH")) > nbirths, timeout=15,
                                     message=f"cycle {n}: NBIRTH after the MQTT drop")
                await async_wait_for(lambda: daemon.publisher.ready, timeout=15, message="publisher ready")
            before = len(observer.on("spBv1.0/plant/DBIRTH/gw/m1"))
            fleet[0].drop_connections()
            await async_wait_for(lambda: len(observer.on("spBv1.0/plant/DBIRTH/gw/m1")) > before, timeout=15,
                                 message=f"cycle {n}: DBIRTH after the CNC drop")
            await async_wait_for(lambda: daemon.pollers["m1"].online, timeout=15, message="poller online")
            births += 1

        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            for n in range(1, 4):  # warm-up: lazily created executor threads, caches
                await cycle(n * MQTT_EVERY)
            start = await settled()
            for n in range(1, CYCLES + 1):
                await cycle(n)
            end = await settled()
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    print(f"\nFIGURES no leaks after {CYCLES} cycles: start={json.dumps(start)} end={json.dumps(end)}")
    assert births == CYCLES + 3
    # A leak is growth: 50 cycles would leave 50+ descriptors, tasks or threads behind.
    assert all(end[key] <= start[key] for key in start), f"after {CYCLES} connect/drop cycles: {start} -> {end}"
