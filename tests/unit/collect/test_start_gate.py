"""The start-up gate: at most K machines between connect and DBIRTH, first come first served, never stuck."""

from __future__ import annotations

import asyncio

import pytest

from edge.collect.start_gate import StartGate, StartTicket


async def test_no_more_than_the_slots_start_at_once_and_every_machine_gets_through() -> None:
    gate = StartGate(3)
    order: list[int] = []

    async def start(machine: int) -> None:
        ticket = StartTicket(gate)
        await ticket.acquire()
        order.append(machine)
        assert gate.starting <= 3
        await asyncio.sleep(0.01)  # the start's reads and birth
        ticket.release()
        ticket.release()  # a second release (the run loop's finally after the birth's) changes nothing

    await asyncio.gather(*(start(i) for i in range(20)))
    assert gate.peak == 3 and gate.starting == 0
    assert order == list(range(20)), "first come, first served"


async def test_a_start_cancelled_while_waiting_or_starting_gives_its_place_back() -> None:
    gate = StartGate(1)
    holder = StartTicket(gate)
    await holder.acquire()
    waiting = StartTicket(gate)
    waiter = asyncio.create_task(waiting.acquire())
    await asyncio.sleep(0)
    waiter.cancel()
    with pytest.raises(asyncio.CancelledError):
        await waiter
    assert not waiting.held
    holder.release()
    late = StartTicket(gate)
    await asyncio.wait_for(late.acquire(), 1.0)
    assert late.held and gate.starting == 1


async def test_without_a_gate_a_ticket_never_waits() -> None:
    ticket = StartTicket(None)
    await ticket.acquire()
    ticket.release()
    assert not ticket.held


def test_a_gate_needs_a_slot() -> None:
    with pytest.raises(ValueError, match="at least 1 slot"):
        StartGate(0)
