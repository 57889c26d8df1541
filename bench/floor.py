"""What a machine-cycle costs before the daemon adds anything: the fleet's polls from one bare process.

The fleet benchmark's simulators, period (100 ms) and poll grid (50 ms, shared TickGrid), polled by N
FocasClients in this process, at two levels:
- round trip: write the tick's prepared request PDU (the daemon's own request for a 100 ms tick,
  bench.workload.daemon_tick_items) and await its answer frame (event loop, kernel, frame decoding:
  nothing else);
- client batch: `FocasClient.batch` of the tick's items (adds the session lock, the request deadline,
  the answer split and the decode of what moved);
- poller: the collector's MachinePollers with the daemon's config for the fleet, handing their changes to
  a sink that drops them (adds scheduling, change detection and Samples: everything but publishing).
CPU is this process's (user+sys) per cycle. The daemon's own figure (`python -m bench fleet`) adds
publishing on top; the difference between the rows is what each layer costs.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import statistics
import tempfile
import time
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import Any

from bench.fleet import start_fleet_sims
from bench.report import Result
from bench.workload import daemon_tick_items, machines_section
from edge.collect.poller import MachinePoller
from edge.collect.tickgrid import TickGrid
from edge.config import parse_config
from edge.focas.client import FocasClient
from edge.focas.frame import PduType
from edge.samples import MetricSpec, Sample
from edge.service.settings import machine_settings

PERIOD_S = 0.1
GRID_S = 0.05
LEVELS = ("round trip", "client batch", "poller")


class DroppingSink:
    """A DeviceSink that publishes nothing: the poller level measures collection alone."""

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        pass

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        pass

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        pass

    async def device_offline(self, device_id: str) -> None:
        pass


def _operation(level: str, cnc: FocasClient) -> Callable[[], Awaitable[Any]]:
    items = daemon_tick_items(PERIOD_S)
    if level == "client batch":
        return lambda: cnc.batch(items)
    # The bench reaches into the client on purpose: the PDU it prepares for the tick, sent as it is.
    data = cnc._prepare(items).pdus[0].layout.data
    return lambda: cnc._roundtrip(data, PduType.DATA_RESPONSE, "floor")


async def _measure(count: Callable[[], int], warmup_s: float, duration_s: float, planned_per_s: float
                   ) -> dict[str, float]:
    await asyncio.sleep(warmup_s)
    cpu_before, cycles_before, started = time.process_time(), count(), time.monotonic()
    await asyncio.sleep(duration_s)
    cpu, done, elapsed = time.process_time() - cpu_before, count() - cycles_before, time.monotonic() - started
    return {"cpu_us_per_cycle": cpu / done * 1e6 if done else math.nan, "cycles_per_s": done / elapsed,
            "achieved_pct": 100 * done / elapsed / planned_per_s}


async def _pollers(ports: list[int], warmup_s: float, duration_s: float) -> dict[str, float]:
    config = parse_config(f"mqtt: {{host: 127.0.0.1, sparkplug: {{group_id: bench, edge_node_id: gw}}}}\n"
                          f"poll_grid_s: {GRID_S}\nmachines:\n{machines_section(ports, PERIOD_S)}", "floor", {})
    grid, sink = TickGrid(config.poll_grid_step_s), DroppingSink()
    with tempfile.TemporaryDirectory(prefix="bench-floor-") as state:
        pollers = [MachinePoller(machine_settings(config, m), sink, Path(state), jitter_s=PERIOD_S, grid=grid)
                   for m in config.machines]
        tasks = [asyncio.create_task(poller.run()) for poller in pollers]
        try:
            return await _measure(lambda: sum(p.stats.ticks for p in pollers), warmup_s, duration_s,
                                  len(ports) / PERIOD_S)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for poller in pollers:
                await poller.close()


async def _poll(ports: list[int], level: str, warmup_s: float, duration_s: float) -> dict[str, float]:
    if level == "poller":
        return await _pollers(ports, warmup_s, duration_s)
    loop = asyncio.get_running_loop()
    grid = TickGrid(GRID_S)
    cycles = 0
    async with contextlib.AsyncExitStack() as stack:
        clients = [await stack.enter_async_context(FocasClient("127.0.0.1", port, timeout=5)) for port in ports]

        async def machine(cnc: FocasClient) -> None:
            nonlocal cycles
            operation = _operation(level, cnc)
            await asyncio.sleep(random.uniform(0, PERIOD_S))  # spread over the period, as the daemon does
            due = loop.time()
            while True:
                await grid.sleep_until(due)
                due += PERIOD_S
                await operation()
                cycles += 1

        tasks = [asyncio.create_task(machine(cnc)) for cnc in clients]
        try:
            return await _measure(lambda: cycles, warmup_s, duration_s, len(ports) / PERIOD_S)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)


def run(quick: bool = False, machines: int = 100, duration_s: float | None = None, repeats: int = 2) -> Result:
    machines = min(machines, 4) if quick else machines
    duration = duration_s or (1.0 if quick else 15.0)
    repeats = 1 if quick else repeats
    result = Result("floor", f"python -m bench floor{' --quick' if quick else ''} --repeat {repeats}")
    sims = start_fleet_sims(machines)
    try:
        ports = [port for sim in sims for port in sim.ports]
        for level in LEVELS:
            runs = [asyncio.run(_poll(ports, level, 0.5 if quick else 3.0, duration)) for _ in range(repeats)]
            cpu = [r["cpu_us_per_cycle"] for r in runs]
            result.rows.append({"level": level, "machines": machines, "runs": repeats,
                                "cpu_us_per_cycle": statistics.median(cpu),
                                "cpu_us_range": f"{min(cpu):.0f}..{max(cpu):.0f}",
                                "achieved_pct": min(r["achieved_pct"] for r in runs)})
            print(f"  floor {level}: {statistics.median(cpu):.0f} us/cycle", flush=True)
    finally:
        for sim in sims:
            sim.stop()
    result.notes.append(f"{machines} clients in one process, period {PERIOD_S * 1000:.0f} ms, grid "
                        f"{GRID_S * 1000:.0f} ms, the fleet's simulators; CPU = this process's user+sys")
    result.notes.append(f"compare with the daemon's figure at the same size: python -m bench fleet --sizes {machines}")
    return result
