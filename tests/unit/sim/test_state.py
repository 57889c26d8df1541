"""The simulated machine's cycle: running, stopping and repeating, parts counted, machines out of step."""

from __future__ import annotations

from edge.focas.model import ParamType
from edge.sim.state_alarms import ALARM_HISTORY_SIZE
from edge.sim.state_program import CycleSpec
from tests.unit.sim.helpers import machine


def test_cycle_runs_stops_and_repeats() -> None:
    state, clock = machine()
    clock.tick(3.0)  # cutting
    cutting = state.status()
    assert (cutting.aut, cutting.run, cutting.motion) == (1, 3, 1)
    assert state.actual_feed() > 0 and state.spindle_speed() > 0
    first = state.positions("absolute")
    clock.tick(0.5)
    assert state.positions("absolute") != first
    clock.tick(8.0)  # 11.5 s: between parts
    idle = state.status()
    assert (idle.run, idle.motion) == (0, 0)
    assert state.actual_feed() == 0.0 and state.spindle_speed() == 0.0
    assert state.sequence_number() == 0
    clock.tick(5.0)  # 16.5 s: the next part is being cut
    assert state.status().run == 3


def test_part_count_increments_once_per_cycle() -> None:
    state, clock = machine(start_parts=7)
    total = state.read_param_value(6712)
    clock.tick(9.9)
    assert state.part_count == 7
    clock.tick(0.2)  # 10.1 s: first part done
    assert state.part_count == 8
    clock.tick(15.0 * 4)  # four more cycles
    assert state.part_count == 12
    assert state.read_param_value(6712) == total + 5
    (record,) = state.read_params(6711, 6711)
    assert (record.number, record.axis, record.type, record.value) == (6711, 0, ParamType.TWO_WORD, 12)


def test_a_long_jump_counts_every_part_and_keeps_the_ring_bounded() -> None:
    state, clock = machine(cycle=CycleSpec(cut_seconds=10.0, idle_seconds=5.0, alarm_every=1))
    clock.tick(15.0 * 100_000)
    assert state.part_count == 100_000
    assert len(state.alarm_history()) == ALARM_HISTORY_SIZE


def test_different_seeds_do_not_run_in_step() -> None:
    a, clock_a = machine(seed=0)
    b, clock_b = machine(seed=3)
    clock_a.tick(2.0)
    clock_b.tick(2.0)
    assert a.positions() != b.positions()
