"""What the event loop's task and future machinery costs a machine-cycle: the floor's round trip, driven three ways.

    python -m bench.loopshape [--machines 100] [--pairs 3] [--duration 6] [--shapes ACB]

The fleet's simulators and the daemon's tick request (bench.workload.daemon_tick_items), 100 ms period, 50 ms
grid, sent by N FocasClients in this process; CPU (user+sys) of this process per answered request, as
`bench floor` measures it. Only the shape of the loop differs:

- A, the floor's round trip level and the daemon's shape: a task per machine awaits the grid slot's future
  (TickGrid.wake_at), writes its request and awaits the answer's arrival future: two task wake-ups a cycle.
- C, one wake-up a cycle: the grid slot's callback writes the request, the task awaits only the answer.
- B, none: the grid slot's callback writes the request; the answer's data_received takes the frame and
  books the machine's next slot. No task, no future.

A - B bounds what restructuring the poller's loop could save (docs/performance.md, "Eighth round"): the
tick's own work stays the same in every shape, so only this difference is at stake.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import random
import statistics
import time
from collections.abc import Callable
from typing import Any

from bench.fleet import start_fleet_sims
from bench.workload import daemon_tick_items
from edge.collect.tickgrid import TickGrid
from edge.focas.client import FocasClient, FrameStream
from edge.focas.frame import PduType

PERIOD_S = 0.1
GRID_S = 0.05
SHAPES = "ACB"


class SlotCalls:
    """One timer per grid slot, as TickGrid, but each entry a callback run in the slot's turn (no future)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, step_s: float) -> None:
        self._loop, self._step = loop, step_s
        self._slots: dict[int, list[tuple[Callable[[Any], None], Any]]] = {}
        self.stopped = False

    def at(self, when: float, call: Callable[[Any], None], arg: Any) -> None:
        index = math.ceil(when / self._step)
        entries = self._slots.get(index)
        if entries is None:
            entries = self._slots[index] = []
            self._loop.call_at(index * self._step, self._fire, index)
        entries.append((call, arg))

    def _fire(self, index: int) -> None:
        entries = self._slots.pop(index, ())
        if not self.stopped:
            for call, arg in entries:
                call(arg)


def _send(pair: tuple[FrameStream, bytes]) -> None:
    pair[0].send(pair[1])


async def _shape(shape: str, ports: list[int], warmup_s: float, duration_s: float) -> float:
    """CPU µs per cycle of one shape (a fresh loop and connections)."""
    loop = asyncio.get_running_loop()
    items = daemon_tick_items(PERIOD_S)
    clients = [FocasClient("127.0.0.1", port, timeout=5) for port in ports]
    for client in clients:
        await client.connect()
    streams = [client._stream for client in clients]  # the bench reaches into the client on purpose
    requests = [client._prepare(items).pdus[0].layout.data for client in clients]
    cycles = 0
    tasks: list[asyncio.Task[None]] = []
    slots = SlotCalls(loop, GRID_S)
    grid = TickGrid(GRID_S)

    async def shape_a(client: FocasClient, data: bytes) -> None:
        nonlocal cycles
        await asyncio.sleep(random.uniform(0, PERIOD_S))
        due = loop.time()
        while True:
            await grid.wake_at(due)
            due += PERIOD_S
            await client._roundtrip(data, PduType.DATA_RESPONSE, "loopshape")
            cycles += 1

    async def shape_c(stream: FrameStream, data: bytes) -> None:
        nonlocal cycles
        frames, pair = stream.frames, (stream, data)
        await asyncio.sleep(random.uniform(0, PERIOD_S))
        due = loop.time()
        while True:
            slots.at(due, _send, pair)
            due += PERIOD_S
            while not frames:
                await stream.arrival()
            frames.pop(0)
            cycles += 1

    def shape_b(stream: FrameStream, data: bytes) -> None:
        frames, decoder, pair = stream.frames, stream._decoder, (stream, data)
        due = loop.time() + random.uniform(0, PERIOD_S)

        def data_received(chunk: bytes) -> None:
            nonlocal cycles, due
            frames.extend(decoder.feed(chunk))
            if frames:
                frames.pop(0)
                cycles += 1
                due += PERIOD_S
                slots.at(due, _send, pair)

        stream.data_received = data_received  # type: ignore[method-assign,assignment]
        slots.at(due, _send, pair)

    for client, stream, data in zip(clients, streams, requests, strict=True):
        assert stream is not None
        if shape == "A":
            tasks.append(asyncio.create_task(shape_a(client, data)))
        elif shape == "C":
            tasks.append(asyncio.create_task(shape_c(stream, data)))
        else:
            shape_b(stream, data)
    await asyncio.sleep(warmup_s)
    cpu_before, cycles_before, started = time.process_time(), cycles, time.monotonic()
    await asyncio.sleep(duration_s)
    cpu, done, elapsed = time.process_time() - cpu_before, cycles - cycles_before, time.monotonic() - started
    slots.stopped = True
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    for client, stream in zip(clients, streams, strict=True):
        if stream is not None and stream.transport is not None:
            stream.transport.abort()
        client._connected = False
    achieved = 100 * done / elapsed / (len(ports) / PERIOD_S)
    us = cpu / done * 1e6 if done else math.nan
    print(f"  shape {shape}: {us:.1f} us/cycle, {achieved:.0f} % of plan", flush=True)
    return us


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.loopshape", description=__doc__.split("\n\n")[0])
    parser.add_argument("--machines", type=int, default=100)
    parser.add_argument("--pairs", type=int, default=3, help="rounds of every shape, alternated")
    parser.add_argument("--duration", type=float, default=6.0)
    parser.add_argument("--warmup", type=float, default=1.5)
    parser.add_argument("--shapes", default=SHAPES)
    args = parser.parse_args()
    sims = start_fleet_sims(args.machines)
    runs: dict[str, list[float]] = {shape: [] for shape in args.shapes}
    try:
        ports = [port for sim in sims for port in sim.ports]
        for _ in range(args.pairs):
            for shape in args.shapes:
                runs[shape].append(asyncio.run(_shape(shape, ports, args.warmup, args.duration)))
    finally:
        for sim in sims:
            sim.stop()
    for shape, values in runs.items():
        print(f"shape {shape}: median {statistics.median(values):.1f} us/cycle "
              f"({', '.join(f'{v:.1f}' for v in values)})")


if __name__ == "__main__":
    main()
