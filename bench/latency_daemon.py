"""The daemon with its latency sources counted: `python -m bench.latency_daemon CONFIG OUT.json`.

Where a sample's time between the CNC's answer and its DDATA goes is a question of the event loop: how late
it runs what is due (loop lag), how long the garbage collector holds it (gc.callbacks), how late the tick
grid's timers fire and how many machines each slot wakes, and how long a tick takes from its request to its
changes reaching the publisher. SIGUSR1 starts a fresh window (the measuring window of `bench fleet
--diagnose`); SIGUSR2 writes the window's figures to OUT.json. The probes cost little (one 10 ms timer,
a clock read per tick and per collection), so the run's other figures stay close to the plain daemon's.
With --spread-clocks (after OUT.json) each machine's CNC clock is bench.clocks' offset off this host's, and the
truth the probes compare with is that machine's own clock.
"""

from __future__ import annotations

import asyncio
import gc
import json
import signal
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench.clocks import device_clock_offset
from edge.collect import poller as poller_module
from edge.collect.tickgrid import TickGrid
from edge.samples import Sample
from edge.service.daemon import Daemon, run_daemon

LAG_PROBE_S = 0.010


def _quantiles(values: Sequence[float]) -> dict[str, float]:
    """p50, p99, max and count of a list of seconds, in milliseconds."""
    if not values:
        return {"n": 0}
    ordered = sorted(values)

    def at(p: float) -> float:
        return ordered[min(len(ordered) - 1, int(p / 100 * len(ordered)))] * 1000

    return {"n": len(ordered), "p50_ms": at(50), "p99_ms": at(99), "max_ms": ordered[-1] * 1000,
            "sum_ms": sum(ordered) * 1000}


class Window:
    """What the probes saw since the last reset."""

    def __init__(self, spread_clocks: bool = False) -> None:
        self.daemon: Daemon | None = None  # its pollers' clocks, at report time
        self.spread_clocks = spread_clocks  # each CNC clock its own (bench.clocks), or all this host's
        self.reset()

    def reset(self) -> None:
        self.started = time.monotonic()
        self.schedstat = _schedstat()
        self.lag: list[float] = []
        self.gc: dict[int, list[float]] = {0: [], 1: [], 2: []}
        self.gc_collected = 0
        self.grid_late: list[float] = []
        self.slot_sizes: Counter[int] = Counter()
        self.tick: list[float] = []  # request sent -> the tick's changes handed to the outputs
        self.publish_lag: list[float] = []  # CNC stamp -> the outputs have the changes (gateway wall clock)
        self.offset_error: list[float] = []  # per tick: the clock offset in use minus the true one (same host)

    def report(self) -> dict[str, Any]:
        gc_all = [d for durations in self.gc.values() for d in durations]
        ran, waited = (after - before for after, before in zip(_schedstat(), self.schedstat, strict=True))
        return {
            "window_s": time.monotonic() - self.started,
            "loop_thread_ran_s": ran,  # on a CPU
            "loop_thread_waited_s": waited,  # runnable, but the host ran something else (a loaded host)
            "loop_lag": _quantiles(self.lag),
            "gc": {f"gen{g}": _quantiles(d) for g, d in self.gc.items()} | {"all": _quantiles(gc_all)},
            "gc_collected": self.gc_collected,
            "gc_tracked_objects": len(gc.get_objects()),
            "gc_frozen_objects": gc.get_freeze_count(),
            "gc_threshold": list(gc.get_threshold()),
            "grid_timer_late": _quantiles(self.grid_late),
            "machines_per_slot": _spread(self.slot_sizes),
            "tick": _quantiles(self.tick),
            "stamp_to_outputs": _quantiles(self.publish_lag),
            "clock": _clock_figures(self),
        }


def _true_offset(window: Window, device_id: str) -> float:
    """The simulated CNC clock of `device_id` minus this host's monotonic clock."""
    cnc_ahead = device_clock_offset(device_id) if window.spread_clocks else 0.0
    return time.time() + cnc_ahead - time.monotonic()


def _clock_figures(window: Window) -> dict[str, Any]:
    """Whether stamp error is the clock offset: its error per tick, and each machine's offset state now."""
    pollers = list(window.daemon.pollers.items()) if window.daemon is not None else []
    now = time.monotonic()
    errors, uncertainties, probes = [], [], []
    for device_id, poller in pollers:
        tracker = poller.clock
        if tracker.offset_s is None:
            continue
        errors.append(abs(tracker.offset_s - _true_offset(window, device_id)))
        uncertainties.append(tracker.uncertainty_at(now) or 0.0)
        probes.append(float(poller._clock.probes.sent))
    return {"tick_offset_error_abs": _quantiles([abs(e) for e in window.offset_error]),
            "machine_offset_error_abs": _quantiles(errors), "machine_uncertainty": _quantiles(uncertainties),
            "probes_sent_per_machine": {"mean": sum(probes) / len(probes) if probes else 0.0,
                                        "max": max(probes, default=0.0)}}


def _schedstat() -> tuple[float, float]:
    """(seconds on a CPU, seconds runnable but waiting for one) of this process's main thread (Linux)."""
    try:
        ran, waited, _ = Path("/proc/self/schedstat").read_text().split()
    except (OSError, ValueError):
        return 0.0, 0.0
    return int(ran) / 1e9, int(waited) / 1e9


def _spread(sizes: Counter[int]) -> dict[str, float]:
    slots = sum(sizes.values())
    if not slots:
        return {"slots": 0}
    ordered = sorted(sizes.elements())
    return {"slots": slots, "min": ordered[0], "p50": ordered[len(ordered) // 2], "max": ordered[-1],
            "mean": sum(ordered) / slots}


def watch_collector(window: Window) -> None:
    """Every collection's pause (by generation) into the window, from gc.callbacks."""
    gc_started = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            gc_started[0] = time.perf_counter()
        else:
            window.gc[info["generation"]].append(time.perf_counter() - gc_started[0])
            window.gc_collected += info["collected"]

    gc.callbacks.append(on_gc)


def watch_grid(window: Window, grid: TickGrid) -> None:
    """How late each grid slot's timer fires, and how many machines it wakes."""
    fire = grid._fire

    def timed_fire(slot: tuple[float, int]) -> None:
        step, index = slot
        window.grid_late.append(asyncio.get_running_loop().time() - index * step)
        window.slot_sizes[len(grid._slots.get(slot, ()))] += 1
        fire(slot)

    grid._fire = timed_fire  # type: ignore[method-assign]


def install(window: Window, daemon: Daemon) -> None:
    """The probes: gc callbacks, the tick grid's timers, the tick, the outputs, a loop-lag timer."""
    window.daemon = daemon
    watch_collector(window)
    watch_grid(window, daemon.tick_grid)
    outputs_data = daemon.outputs.device_data

    async def timed_data(device_id: str, samples: Sequence[Sample]) -> None:
        if samples:
            cnc_ahead = device_clock_offset(device_id) if window.spread_clocks else 0.0
            window.publish_lag.append(time.time() + cnc_ahead - samples[0].timestamp_ms / 1000)
        await outputs_data(device_id, samples)

    daemon.outputs.device_data = timed_data  # type: ignore[method-assign]
    tick = poller_module.MachinePoller._tick

    async def timed_tick(self: Any, plan: Any, groups: Any) -> Any:
        started = time.monotonic()
        result = await tick(self, plan, groups)
        window.tick.append(time.monotonic() - started)
        offset = self.clock.offset_s
        if offset is not None and not self.clock.use_gateway_time:
            window.offset_error.append(offset - _true_offset(window, self.machine_id))
        return result

    poller_module.MachinePoller._tick = timed_tick  # type: ignore[method-assign]
    asyncio.get_running_loop().create_task(lag_probe(window), name="latency-lag-probe")


async def lag_probe(window: Window) -> None:
    """How late a 10 ms timer runs, over and over: the loop's lag as any callback due then sees it."""
    loop = asyncio.get_running_loop()
    while True:
        due = loop.time() + LAG_PROBE_S
        await asyncio.sleep(LAG_PROBE_S)
        window.lag.append(loop.time() - due)


def main() -> int:
    config, out = Path(sys.argv[1]), Path(sys.argv[2])
    window = Window(spread_clocks="--spread-clocks" in sys.argv[3:])
    signal.signal(signal.SIGUSR1, lambda signum, frame: window.reset())
    signal.signal(signal.SIGUSR2, lambda signum, frame: out.write_text(json.dumps(window.report(), indent=1)))
    configure: Callable[[Daemon], None] = lambda daemon: install(window, daemon)  # noqa: E731
    return run_daemon(config, configure)


if __name__ == "__main__":
    sys.exit(main())
