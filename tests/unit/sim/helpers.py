"""The simulated machine on a fake clock, for the simulator's unit tests."""

from __future__ import annotations

from edge.sim.state import MachineState
from edge.sim.state_program import CycleSpec

T0 = 1_750_000_000.0  # 2025-06-15 15:06:40 UTC


class FakeClock:
    def __init__(self, start: float = T0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def tick(self, seconds: float) -> None:
        self.now += seconds


def machine(profile: str = "30i", **kwargs: object) -> tuple[MachineState, FakeClock]:
    clock = FakeClock()
    cycle = kwargs.pop("cycle", CycleSpec(cut_seconds=10.0, idle_seconds=5.0))
    state = MachineState(profile, time_source=clock, cycle=cycle, **kwargs)  # type: ignore[arg-type]
    return state, clock
