"""The plant page at fleet size: render time of `/` 's fleet overview and of one machine page, the recorder's
cost per tick and its memory per machine, with 24 h of made-up history per machine.

In process, with a fake clock: each machine flaps between running, idle, feed hold and alarm every 20-200 s
for a day (far more often than a real machine, to fill the bounded stores), sends spindle load and feed every
status tick of its last hour, and raises an alarm now and then. Nothing here touches a network.
"""

from __future__ import annotations

import json
import random
import statistics
import time
import tracemalloc
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any
from zoneinfo import ZoneInfo

from bench.report import Check, Result
from edge.samples import MetricType, Sample
from edge.service.plant_page import fleet_block, render_machine
from edge.service.trends import TrendRecorder

SIZES = (100, 1000)
RUN_STATES = ("START", "RESET", "HOLD", "START")
FLEET_RENDER_TARGET_MS = 200.0
MACHINE_RENDER_TARGET_MS = 50.0
NOW = 1_764_068_400.0
TIMED = 50  # machines whose day is timed (building the samples and the alarm JSON included)


class Clock:
    def __init__(self) -> None:
        self.now = NOW - 86_400.0

    def __call__(self) -> float:
        return self.now


def _history(recorder: TrendRecorder, clock: Clock, machine_id: str, seed: int) -> int:
    """A day of one machine; returns how many status batches it took."""
    rng = random.Random(seed)
    t = NOW - 86_400.0
    batches = 0
    while t < NOW:
        clock.now = t
        alarm = "ALM" if rng.random() < 0.05 else ""
        samples = [Sample("Status/Run", rng.choice(RUN_STATES), MetricType.STRING, 0),
                   Sample("Status/Alarm", alarm, MetricType.STRING, 0)]
        if t > NOW - 3600:
            samples += [Sample("Spindle/1/Load", rng.uniform(5, 90), MetricType.DOUBLE, 0),
                        Sample("Feed/Actual", rng.uniform(0, 1500), MetricType.DOUBLE, 0)]
        if alarm:
            event = {"event": "raised", "type": 2, "number": 1000 + rng.randrange(50), "axis": 0,
                     "message": "COOLANT LEVEL LOW", "timestamp_ms": int(t * 1000)}
            samples.append(Sample("Alarm/Event", json.dumps(event), MetricType.STRING, 0))
        recorder.observe(machine_id, samples)
        batches += 1
        t += rng.uniform(20, 200) if t < NOW - 3600 else 5.0
    return batches


def _pollers(count: int) -> dict[str, Any]:
    zone = ZoneInfo("Europe/Berlin")
    return {f"m{i:04d}": SimpleNamespace(online=i % 50 != 0, online_changed_at=NOW - 600,
                                         machine=SimpleNamespace(zone=zone)) for i in range(count)}


def _best_ms(render: Any, repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        render()
        times.append((time.perf_counter() - started) * 1000)
    return min(times), statistics.median(times)


def measure(size: int) -> dict[str, Any]:
    """One fleet size: record a day per machine, then time the renders."""
    clock = Clock()
    pollers = _pollers(size)
    timed = TrendRecorder(clock)  # the recording cost, without tracemalloc's overhead, on a few machines
    started = time.perf_counter()
    batches = sum(_history(timed, clock, machine_id, i) for i, machine_id in enumerate(list(pollers)[:TIMED]))
    record_s = time.perf_counter() - started
    recorder = TrendRecorder(clock)
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for i, machine_id in enumerate(pollers):
        _history(recorder, clock, machine_id, i)
    kept = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    clock.now = NOW
    fleet_best, fleet_median = _best_ms(lambda: fleet_block(pollers, recorder, NOW), 5)
    one = next(iter(pollers))
    page_best, page_median = _best_ms(lambda: render_machine(one, pollers[one], recorder.machine(one), NOW), 5)
    return {"machines": size, "record_us_per_batch": round(record_s / batches * 1e6, 2),
            "kb_per_machine": round(kept / size / 1024, 1),
            "fleet_render_ms_best": round(fleet_best, 3), "fleet_render_ms_median": round(fleet_median, 3),
            "fleet_html_kb": round(len(fleet_block(pollers, recorder, NOW).encode()) / 1024),
            "machine_page_ms_best": round(page_best, 3), "machine_page_ms_median": round(page_median, 3)}


def run(quick: bool = False, sizes: Sequence[int] | None = None) -> Result:
    result = Result("plantpage", "python -m bench plantpage")
    result.rows = [measure(size) for size in (sizes or (SIZES[:1] if quick else SIZES))]
    biggest = result.rows[-1]
    result.checks.append(Check(f"fleet overview render at {biggest['machines']} machines",
                               biggest["fleet_render_ms_median"], FLEET_RENDER_TARGET_MS, "<=", " ms"))
    result.checks.append(Check("one machine page render", biggest["machine_page_ms_median"],
                               MACHINE_RENDER_TARGET_MS, "<=", " ms"))
    result.notes.append("history: a status change every 20-200 s for 24 h, spindle load + feed every 5 s in the "
                        "last hour, an alarm in 5 % of the changes; kb_per_machine is what tracemalloc saw kept")
    return result
