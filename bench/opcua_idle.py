"""What the OPC UA server costs per data batch when no client subscribes, counted in one process.

The fleet benchmark's `idle` mode (server on, no client) swings by tens of µs per machine-cycle between runs;
this isolates the hand-over itself: each machine's batch of changed samples goes through `Outputs` (a
publisher that does nothing, then the OPC UA output on this loop, which applies the batch in the call) and
the process CPU per batch is compared with the same batches through `Outputs` without the output.

    python -m bench.opcua_idle [--machines 100] [--metrics 74] [--ticks 200] [--rounds 3] [--profile]
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import pstats
import time
from typing import Any

from bench.floor import DroppingSink
from bench.opcua_notify import CHANGED_PER_TICK, _sample, metric_specs, server_settings
from edge.opcua.output import OpcUaOutput
from edge.samples import Sample
from edge.service.outputs import Outputs


async def _feed(outputs: Outputs, batches: list[list[list[Sample]]], names: list[str]) -> float:
    started = time.process_time()
    for tick in batches:
        for name, batch in zip(names, tick, strict=True):
            await outputs.device_data(name, batch)
    return time.process_time() - started


async def measure(machines: int, metrics: int, ticks: int, rounds: int, profile: bool) -> dict[str, Any]:
    output = OpcUaOutput(server_settings("opcua-idle-"))
    await output.start()
    try:
        specs = metric_specs(metrics)
        names = [f"m{m}" for m in range(machines)]
        now_ms = int(time.time() * 1000)
        for name in names:
            await output.device_online(name, specs, [_sample(s, 0, now_ms) for s in specs])
        while output.pending:  # the births, applied by the drain  # noqa: ASYNC110 - a bench, polling is fine
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.05)
        step = max(1, int(1 / CHANGED_PER_TICK))
        batches = [[[_sample(spec, tick, now_ms + tick) for spec in specs[(tick + m) % step::step]]
                    for m in range(machines)] for tick in range(1, ticks + 1)]
        cycles = machines * ticks
        bare, served = Outputs(DroppingSink()), Outputs(DroppingSink(), [output])
        without: list[float] = []
        with_server: list[float] = []
        profiler = cProfile.Profile() if profile else None
        for _ in range(rounds):
            without.append(await _feed(bare, batches, names) / cycles * 1e6)
            if profiler is not None:
                profiler.enable()
            with_server.append(await _feed(served, batches, names) / cycles * 1e6)
            if profiler is not None:
                profiler.disable()
        if profiler is not None:
            pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
        extra = [w - b for w, b in zip(with_server, without, strict=True)]
        return {"machines": machines, "values_per_batch": sum(map(len, batches[0])) / machines,
                "us_per_batch_without": [round(x, 2) for x in without],
                "us_per_batch_with_server": [round(x, 2) for x in with_server],
                "extra_us_per_batch": [round(x, 2) for x in extra], "extra_us_min": round(min(extra), 2),
                "dropped": output.dropped, "failures": output.failures}
    finally:
        await output.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machines", type=int, default=100)
    parser.add_argument("--metrics", type=int, default=74)
    parser.add_argument("--ticks", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args()
    print(asyncio.run(measure(args.machines, args.metrics, args.ticks, args.rounds, args.profile)))


if __name__ == "__main__":
    main()
