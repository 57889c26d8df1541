"""Item plans shared by every session of the process asking for the same item of the same kind of control."""

from __future__ import annotations

from edge.focas import items as it
from edge.focas.function_entry import Context
from edge.focas.native import plan_item, shared_plan_item
from edge.focas.values import SlotForm


def test_one_plan_per_item_context_and_path_equal_to_a_fresh_one() -> None:
    item = it.ReadMacros(500, 509)
    plan = shared_plan_item(it.ReadMacros(500, 509), Context(), 1)
    assert shared_plan_item(item, Context(), 1) is plan
    assert plan == plan_item(item, Context(), 1)
    assert shared_plan_item(item, Context(), 2) is not plan, "another path, other request subpackets"
    other = Context(max_axis=32, slot_form=SlotForm.SCALED)
    assert shared_plan_item(it.ReadPositions("absolute"), other, 1) is not shared_plan_item(
        it.ReadPositions("absolute"), Context(), 1)


def test_a_plan_that_carries_an_error_is_planned_afresh_each_time() -> None:
    item = it.ReadMacros(509, 500)  # last before first: the item itself is wrong
    first = shared_plan_item(item, Context(), 1)
    assert first.error is not None
    assert shared_plan_item(item, Context(), 1) is not first
