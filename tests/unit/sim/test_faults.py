"""Fault plans: counted faults clear themselves, hang_on aims at one function."""

from __future__ import annotations

import pytest

from edge.sim.faults import FaultPlan


def test_counted_faults_clear_themselves() -> None:
    plan = FaultPlan(hang=2, drop_after=2, refuse=-1)
    assert [plan.take_hang() for _ in range(3)] == [True, True, False]
    assert [plan.take_drop() for _ in range(3)] == [False, True, False]
    assert all(plan.take_refuse() for _ in range(5))
    plan.update({"ew": {"0x15": 6, "read_pmc": 18}})
    assert plan.ew_for(0x15, "read_macros") == 6 and plan.ew_for(0x8001, "read_pmc") == 18
    plan.clear()
    assert plan.describe()["refuse"] == 0 and plan.ew_for(0x15, "read_macros") is None
    with pytest.raises(ValueError, match="unknown fault"):
        plan.update({"explode": 1})


def test_hang_on_aims_at_one_function_and_counts_down() -> None:
    from edge.sim.faults import FaultPlan

    faults = FaultPlan()
    faults.update({"hang_on": {"write_macros": 1, "0x8002": -1}})
    assert not faults.take_hang_on([(0x15, "read_macros"), (0x45, "read_clock")])  # polls never hang
    assert faults.take_hang_on([(0x16, "write_macros")])
    assert not faults.take_hang_on([(0x16, "write_macros")])  # once
    assert faults.take_hang_on([(0x8002, "write_pmc")]) and faults.take_hang_on([(0x8002, "write_pmc")])
    assert faults.describe()["hang_on"] == {"write_macros": 0, str(0x8002): -1}
