"""The shared poll grid: wake-ups on grid points, never early, one timer per slot, sleepers independent."""

from __future__ import annotations

import asyncio
import math

import pytest

from edge.collect.tickgrid import TickGrid


async def test_a_wakeup_is_on_the_grid_point_at_or_after_the_deadline() -> None:
    grid = TickGrid(0.01)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + 0.023
    await grid.sleep_until(deadline)
    woke = loop.time()
    assert woke >= grid.slot_time(deadline) >= deadline
    assert grid.slot_time(deadline) - deadline < 0.01


async def test_machines_due_in_one_slot_share_one_timer_and_one_loop_turn() -> None:
    grid = TickGrid(0.01)
    loop = asyncio.get_running_loop()
    base = grid.slot_time(loop.time() + 0.02)
    order: list[str] = []

    async def machine(name: str, due: float) -> None:
        await grid.sleep_until(due)
        order.append(name)

    tasks = [asyncio.create_task(machine(n, base - d)) for n, d in (("a", 0.001), ("b", 0.005), ("c", 0.009))]
    await asyncio.sleep(0)
    assert grid.pending_slots == 1
    first = await asyncio.wait_for(asyncio.gather(*tasks), 1.0)
    assert first == [None, None, None] and sorted(order) == ["a", "b", "c"]
    assert grid.pending_slots == 0


async def test_cancelling_one_sleeper_leaves_the_others_on_time() -> None:
    grid = TickGrid(0.01)
    loop = asyncio.get_running_loop()
    due = loop.time() + 0.015
    victim = asyncio.create_task(grid.sleep_until(due))
    survivor = asyncio.create_task(grid.sleep_until(due))
    await asyncio.sleep(0)
    victim.cancel()
    await asyncio.wait_for(survivor, 1.0)
    assert victim.cancelled() and loop.time() >= due


async def test_a_deadline_in_the_past_returns_at_once() -> None:
    grid = TickGrid(0.01)
    loop = asyncio.get_running_loop()
    await asyncio.wait_for(grid.sleep_until(loop.time() - 5), 0.5)
    assert grid.pending_slots == 0


def test_the_step_must_be_positive() -> None:
    with pytest.raises(ValueError, match="step"):
        TickGrid(0)
    grid = TickGrid(0.01)
    with pytest.raises(ValueError, match="step"):
        grid.step_s = -1.0
    assert grid.step_s == 0.01


async def test_a_step_changed_while_machines_sleep_keeps_their_slot_and_applies_to_the_next_sleep() -> None:
    grid = TickGrid(0.04)
    loop = asyncio.get_running_loop()
    # Slots half a second ahead: a busy host between the two sleepers must not let the first one fire.
    due = loop.time() + 0.5
    old_slot = grid.slot_time(due)
    sleeper = asyncio.create_task(grid.sleep_until(due))
    await asyncio.sleep(0)
    grid.step_s = 0.03  # a reload: slot (0.03, k) must not be taken for the armed (0.04, k)
    new_due = loop.time() + 0.5
    newcomer = asyncio.create_task(grid.sleep_until(new_due))
    await asyncio.sleep(0)
    assert grid.pending_slots == 2
    await asyncio.wait_for(sleeper, 5.0)
    assert loop.time() >= old_slot
    await asyncio.wait_for(newcomer, 5.0)
    assert loop.time() >= math.ceil(new_due / 0.03) * 0.03 == grid.slot_time(new_due)
    assert grid.pending_slots == 0
