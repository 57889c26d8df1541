"""A replayed tick's time by layer: bench.tickreplay's replay with a timer around each layer's entry point.

    python -m bench.tickparts REC [--machines N]

The replay's per-tick cost model (`tickreplay replay --per-tick`) fits one coefficient per feature, but at 1 Hz
the servo loads, the new CNC second and most moved reads come on every tick together, so the fit cannot tell
them apart (it gave the new second ~40 us, and negative costs per published value). This times the layers
themselves instead: the client's batch (with the answer split inside it), the clock's observe, decode and
Clock/* samples, change detection (`report`) and the DATA encoding (`device_data`). Each layer's time includes
the timed layers it calls; the tick's own loop is what `_tick` takes beyond the timed calls it makes. Each
timer costs ~0.1-0.2 us a call (report is called ~10-20 times a tick), so compare recordings and trees with
this tool, and not its totals with `tickreplay replay`'s figures.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import tickreplay
from edge.collect import changes, clock_feed
from edge.collect import poller as poller_module
from edge.focas import client as client_module
from edge.focas import frame
from edge.publish import node

# (owner, attribute, label): the timed entry points; `_tick` first, the rest inside it (device_data after it)
LAYERS: tuple[tuple[Any, str, str], ...] = (
    (poller_module.MachinePoller, "_tick", "tick, in all"),
    (client_module.FocasClient, "_batch", "client batch (split and decode)"),
    (frame.AnswerSplitter, "split", "  of which the answer split"),
    (poller_module.MachinePoller, "_observe_clock", "clock: observe (tracker)"),
    (client_module, "clock_value", "clock: decode a new second"),
    (clock_feed.ClockFeed, "samples", "clock: Clock/* samples"),
    (changes.ChangeDetector, "report", "change detection (report)"),
    (node.SparkplugNode, "device_data", "DATA encoding (device_data)"),
)


class Timers:
    """Per label, ns (inclusive) and calls, and the ns of its timed callees; counted only while `on` (after the
    replay's warm-up round). The replay never suspends inside a tick, so the timed calls nest as a stack."""

    def __init__(self) -> None:
        self.ns: collections.Counter[str] = collections.Counter()
        self.callees_ns: collections.Counter[str] = collections.Counter()
        self.callees: collections.Counter[str] = collections.Counter()
        self.calls: collections.Counter[str] = collections.Counter()
        self.stack: list[str] = []
        self.on = False

    def _done(self, label: str, took: int) -> None:
        self.stack.pop()
        if self.on:
            self.ns[label] += took
            self.calls[label] += 1
            if self.stack:
                self.callees_ns[self.stack[-1]] += took
                self.callees[self.stack[-1]] += 1

    def wrap(self, function: Callable[..., Any], label: str) -> Callable[..., Any]:
        clock = time.perf_counter_ns
        if asyncio.iscoroutinefunction(function):
            async def timed_async(*args: Any, **kwargs: Any) -> Any:
                self.stack.append(label)
                began = clock()
                result = await function(*args, **kwargs)
                self._done(label, clock() - began)
                return result
            return timed_async

        def timed(*args: Any, **kwargs: Any) -> Any:
            self.stack.append(label)
            began = clock()
            result = function(*args, **kwargs)
            self._done(label, clock() - began)
            return result
        return timed


def wrapper_costs(calls: int = 200_000) -> tuple[float, float]:
    """ns a timed call adds (a) to its caller's own time, beyond what it measures, and (b) to what it measures,
    beyond the bare call: from a timed no-op. `run` takes them off."""
    def noop() -> None:
        return None

    timers = Timers()
    timers.on = True
    timed = timers.wrap(noop, "noop")
    timers.stack.append("caller")
    clock = time.perf_counter_ns
    began = clock()
    for _ in range(calls):
        noop()
    bare = clock() - began
    began = clock()
    for _ in range(calls):
        timed()
    outer = clock() - began
    return (outer - timers.ns["noop"]) / calls, (timers.ns["noop"] - bare) / calls


def run(recording: dict[str, Any], machines: int) -> dict[str, tuple[float, float]]:
    """Per label, (us a tick, calls a tick) over one replayed round after the warm-up round."""
    timers = Timers()
    originals = [(owner, name, getattr(owner, name)) for owner, name, _ in LAYERS]
    warm_up = len(recording["ticks"]) * machines
    seen = 0
    try:
        for owner, name, label in LAYERS:
            setattr(owner, name, timers.wrap(getattr(owner, name), label))
        timed_tick = poller_module.MachinePoller._tick

        async def counting(self: poller_module.MachinePoller, plan: Any, groups: Any) -> Any:
            nonlocal seen
            seen += 1
            timers.on = seen > warm_up
            return await timed_tick(self, plan, groups)

        poller_module.MachinePoller._tick = counting  # type: ignore[method-assign]
        asyncio.run(tickreplay._replay(recording, machines, 1, "daemon"))
    finally:
        for owner, name, original in originals:
            setattr(owner, name, original)
    ticks = seen - warm_up
    to_caller, to_callee = wrapper_costs()
    parts = {label: ((timers.ns[label] - timers.calls[label] * to_callee) / ticks / 1000, timers.calls[label] / ticks)
             for _, _, label in LAYERS}
    tick = LAYERS[0][2]
    own = timers.ns[tick] - timers.callees_ns[tick] - timers.callees[tick] * (to_caller - to_callee)
    parts["tick's own loop (_tick less its timed callees)"] = (own / ticks / 1000, 1.0)
    return parts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path, help="a bench.tickreplay recording")
    parser.add_argument("--machines", type=int, default=100)
    args = parser.parse_args()
    for label, (us, calls) in run(pickle.loads(args.file.read_bytes()), args.machines).items():
        print(f"{label:38} {us:7.2f} us a tick ({calls:.2f} calls)")


if __name__ == "__main__":
    main()
