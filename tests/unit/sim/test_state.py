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


def test_feed_hold_stops_the_cut_until_cycle_start_and_no_part_is_counted_meanwhile() -> None:
    state, clock = machine(start_parts=7)  # cut 10 s, idle 5 s
    clock.tick(4.0)  # cutting
    state.set_feed_hold(True)
    held_at = (state.positions("absolute"), state.positions("machine"), state.sequence_number())
    clock.tick(37.0)  # two and a half cycles of real time, all of it held
    held = state.status()
    assert (held.run, held.motion) == (2, 0)
    assert (state.positions("absolute"), state.positions("machine"), state.sequence_number()) == held_at
    assert state.actual_feed() == 0.0 and state.spindle_loads()[0] == 0.0
    assert state.spindle_speed() > 0  # the spindle turns on in feed hold, as on a real control
    assert state.part_count == 7
    assert state.read_pmc_bytes("F", 0, 0)[0] & 0b0011_0000 == 0b0001_0000  # SPL (hold lamp) on, STL off
    state.set_feed_hold(False)  # cycle start: the cut goes on from where it stood
    assert state.status().run == 3 and state.actual_feed() > 0
    assert state.positions("absolute") == held_at[0]
    clock.tick(5.9)
    assert state.part_count == 7  # 4 s cut before the hold + 5.9 s after: not done yet
    clock.tick(0.2)
    assert state.part_count == 8
    clock.tick(15.0)
    assert state.part_count == 9  # one part per cycle again, the held 37 s left out


def test_a_cycle_alarm_after_a_feed_hold_is_stamped_with_its_real_instant() -> None:
    state, clock = machine(cycle=CycleSpec(cut_seconds=10.0, idle_seconds=5.0, alarm_every=1))
    before = len(state.alarm_history())  # the seeded history
    clock.tick(2.0)
    state.set_feed_hold(True)
    clock.tick(100.0)
    state.set_feed_hold(False)
    clock.tick(8.6)  # the cut ends 8 s after the release; the cycle alarm comes 0.5 s later
    [event, *_] = state.alarm_events()
    assert len(state.alarm_history()) == before + 1
    assert abs(event.utc_time.timestamp() - (clock.now - 0.1)) < 1e-3


def test_a_pinned_moment_holds_the_cycle_of_every_path_until_unpinned() -> None:
    state, clock = machine("31i-2p")
    second = state.for_path(2)
    assert second is not None
    clock.tick(3.0)
    state.pin_moment()
    pinned = state.positions("absolute"), second.positions("absolute")
    clock.tick(0.5)  # a request's reads all see the moment it was pinned at
    assert (state.positions("absolute"), second.positions("absolute")) == pinned
    state.unpin_moment()
    assert (state.positions("absolute"), second.positions("absolute")) != pinned
