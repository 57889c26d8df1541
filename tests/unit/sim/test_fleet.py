"""A fleet's machines on a fake clock."""

from __future__ import annotations

from edge.sim.fleet import Fleet, MachineSpec
from tests.unit.sim.helpers import FakeClock


def test_fleet_machines_raise_and_clear_alarms_by_default() -> None:
    clock = FakeClock()
    fleet = Fleet([MachineSpec(profile="0i-F", seed=0)], base_port=0, time_source=clock)
    state = fleet[0].state
    seen: set[int] = set()
    for _ in range(3 * 16 * 4):  # three 16-second cycles in quarter seconds
        clock.tick(0.25)
        seen.update(a.number for a in state.active_alarms())
    assert seen, "no alarm came during three cycles"
    clock.tick(8.0)
    assert state.active_alarms() == []
