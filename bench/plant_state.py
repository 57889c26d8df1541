"""`python -m bench.plant_state`: what the derived state and utilisation cost per event, in isolation.

The fleet benchmark (`python -m bench fleet`) measures them inside a machine-cycle, where they are within its
run-to-run spread; these are the per-event costs behind that, to multiply by how often each event happens
(issue 27: derive only when the status word changed, count only at a change of state and the minute).
"""

from __future__ import annotations

import tempfile
import time
import timeit
from collections.abc import Callable
from pathlib import Path
from zoneinfo import ZoneInfo

from edge.collect.changes import ChangeDetector
from edge.collect.execution import derive
from edge.collect.plant_state import PlantState
from edge.focas.model import StatInfo

CUTTING, DWELL, HELD = StatInfo(1, 3, 1, 0, 0, 0, 0), StatInfo(1, 3, 2, 0, 0, 0, 0), StatInfo(1, 2, 0, 0, 0, 0, 0)


def per_call_us(action: Callable[[], object], number: int, repeat: int = 5) -> float:
    """Best of `repeat` runs, microseconds per call."""
    return min(timeit.repeat(action, number=number, repeat=repeat)) / number * 1e6


def main() -> None:
    state = PlantState("bench", ZoneInfo("Europe/Berlin"), Path(tempfile.mkdtemp(prefix="bench-plant-")))
    changes = ChangeDetector()
    now = int(time.time() * 1000)
    state.status(CUTTING, now)
    step = [0]

    def change_of_state() -> None:
        step[0] += 1
        changes.filter(state.status(HELD if step[0] % 2 else CUTTING, now + step[0]))

    def minute() -> None:
        step[0] += 1
        changes.filter(state.minute(now + step[0] * 60_000))

    def save() -> None:
        step[0] += 1
        state.store.save(step[0], state.counter.to_json())

    rows = [
        ("derive (a status word seen before)", per_call_us(lambda: derive(DWELL), 100_000)),
        ("status word changed, same state", per_call_us(lambda: state.status(DWELL, now), 100_000)),
        ("change of state: count, one counter, change filter", per_call_us(change_of_state, 20_000)),
        ("minute publish: count, one counter, change filter", per_call_us(minute, 20_000)),
        ("save (atomic write + fsync, in a worker thread)", per_call_us(save, 50, repeat=3)),
    ]
    for name, us in rows:
        print(f"{name:55s} {us:10.2f} µs")


if __name__ == "__main__":
    main()
