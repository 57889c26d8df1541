"""Throughput of a function: calls per second over repeated timed runs (best and median reported)."""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Rate:
    """Units per second: the best run (least disturbed by other load) and the median of all runs."""

    best: float
    median: float
    worst: float
    runs: int


def measure_rate(call: Callable[[], object], units_per_call: int, seconds: float = 1.0, repeats: int = 5) -> Rate:
    """Call `call` in a tight loop for about `seconds` per run, `repeats` runs; GC paused while timing."""
    loops = _calibrate(call, seconds)
    rates: list[float] = []
    enabled = gc.isenabled()
    gc.disable()
    try:
        for _ in range(repeats):
            start = time.perf_counter()
            for _ in range(loops):
                call()
            elapsed = time.perf_counter() - start
            rates.append(loops * units_per_call / elapsed)
    finally:
        if enabled:
            gc.enable()
    return Rate(max(rates), statistics.median(rates), min(rates), repeats)


def _calibrate(call: Callable[[], object], seconds: float) -> int:
    """How many calls take about `seconds`."""
    loops = 1
    while True:
        start = time.perf_counter()
        for _ in range(loops):
            call()
        elapsed = time.perf_counter() - start
        if elapsed >= 0.05 or loops >= 1 << 24:
            return max(1, int(loops * seconds / max(elapsed, 1e-9)))
        loops *= 4
