"""A simulated fleet in its own process, driven over stdin/stdout by a benchmark.

    python -m bench.simproc --machines 50 [--latency 0.002] [--stamp-macro 509] [--clock-macro 508]
                            [--fill-macros 500-599] [--spread-clocks FIRST]

Prints one JSON line ``{"ports": [...]}`` when every machine listens, then answers each ``stats`` line
on stdin with a JSON line (data PDUs and subpackets served, this process's CPU seconds); ``stop`` or
end of input closes the fleet. With --stamp-macro each machine sets that macro to its own wall-clock
time (seconds modulo 1000, millisecond resolution) at random moments, so a subscriber can tell how
long a change took to reach the broker: latency = receipt time - value (mod 1000). With --clock-macro that
macro reads as the CNC's clock at the moment it answers, so a published timestamp minus its value is the
timestamp's error (edge.sim.state_clock.clock_macro_error). With --spread-clocks FIRST machine i's CNC clock
runs bench.clocks.cnc_clock_offset(FIRST + i) off this host's (FIRST: its index in the whole fleet); without it
every CNC clock is this host's.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import json
import os
import random
import sys
import time

from bench.clocks import cnc_clock_offset
from edge.sim import CycleSpec, Fleet, MachineSpec

STAMP_MODULO = 1000.0
WRITE_LOG_LIMIT = 1000


def stamp_value(now: float) -> float:
    """The value a stamp macro carries for a change at `now` (epoch seconds)."""
    return round(now % STAMP_MODULO, 3)


def stamp_latency(value: float, received: float) -> float:
    """Seconds from the change a stamp `value` records to `received` (epoch seconds)."""
    return (received - value) % STAMP_MODULO


STAMP_TICK_S = 0.1  # how often the stamper looks for due changes: one wake-up per tick, not one per change


async def stamp_changes(fleet: Fleet, macro: int, low: float, high: float, tick_s: float = STAMP_TICK_S) -> None:
    """Every machine changes `macro` to the current time at random intervals in [low, high) seconds.

    The stamper wakes on a fixed tick and writes every change that fell due since: a wake-up per change cost
    a 50-machine process 0.013 cores (120 wake-ups a second), which a 1,000-machine run paid twenty times over.
    A change's value is the clock when it is written, so the latency it measures keeps its meaning; only the
    moments of change move by up to one tick.
    """
    due = [time.time() + random.uniform(0, high) for _ in fleet]
    while True:
        now = time.time()
        for index, machine in enumerate(fleet):
            if due[index] <= now:
                machine.state.write_macro(macro, stamp_value(time.time()), protocol="bench")
                due[index] = now + random.uniform(low, high)
                if len(machine.state.write_log) > WRITE_LOG_LIMIT:
                    machine.state.write_log.clear()
        await asyncio.sleep(tick_s)


def stats(fleet: Fleet) -> dict[str, float]:
    times = os.times()
    return {"data_pdus": sum(m.native.stats.data_pdus for m in fleet),
            "clock_pdus": sum(m.native.stats.clock_pdus for m in fleet),
            "subpackets": sum(m.native.stats.subpackets for m in fleet),
            "cpu_s": times.user + times.system, "time": time.time()}


async def serve(args: argparse.Namespace) -> None:
    first, _, last = args.fill_macros.partition("-") if args.fill_macros else ("", "", "")
    numbers = range(int(first), int(last or first) + 1) if first else range(0)
    macros: dict[int, float | None] = {n: float(n) + 0.5 for n in numbers}
    specs = [MachineSpec(profile=args.profile, macros=macros, faults={"latency": args.latency},
                         cycle=CycleSpec(alarm_every=0), clock_macro=args.clock_macro or None,
                         clock_offset=0.0 if args.spread_clocks < 0 else cnc_clock_offset(args.spread_clocks + i))
             for i in range(args.machines)]
    fleet = Fleet(specs, base_port=0, packed_base_port=0 if args.packed else None)
    await fleet.start()
    gc.collect()
    gc.freeze()  # the fleet lives as long as the process: collections need not walk it (~6 % of its CPU)
    stamper = None
    if args.stamp_macro:
        stamper = asyncio.create_task(stamp_changes(fleet, args.stamp_macro, args.stamp_min, args.stamp_max))
    print(json.dumps({"ports": [m.port for m in fleet], "packed_ports": [m.packed_port for m in fleet],
                      "pid": os.getpid()}), flush=True)
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    try:
        while line := await reader.readline():
            command = line.decode().strip()
            if command == "stats":
                print(json.dumps(stats(fleet)), flush=True)
            elif command == "stop":
                break
    finally:
        if stamper is not None:
            stamper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await stamper
        await fleet.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--machines", type=int, default=1)
    parser.add_argument("--profile", default="30i")
    parser.add_argument("--latency", type=float, default=0.0, help="seconds before each answer")
    parser.add_argument("--stamp-macro", type=int, default=0)
    parser.add_argument("--clock-macro", type=int, default=0, help="a macro that reads as the CNC clock")
    parser.add_argument("--stamp-min", type=float, default=0.2)
    parser.add_argument("--stamp-max", type=float, default=0.6)
    parser.add_argument("--packed", action="store_true", help="also serve the packed surface")
    parser.add_argument("--fill-macros", default="",
                        help="give macros FIRST-LAST a value (pyfocas cannot read vacant ones)")
    parser.add_argument("--spread-clocks", type=int, default=-1, metavar="FIRST",
                        help="give each CNC clock its own offset (bench.clocks), FIRST being the fleet index of the "
                             "first machine (default: every CNC clock is this host's)")
    asyncio.run(serve(parser.parse_args()))


if __name__ == "__main__":
    main()
