"""The start-up gate: at most K machines between their CNC session's connect and their DBIRTH at a time.

Why: a machine's start (static reads, path count, the first full tick, plan and birth) costs the event loop
milliseconds. At 1,000 machines on a starved host, hundreds starting at once put so much work in front of
every answer that the 5 s request deadlines expired on answers the CNCs had long sent: sessions were dropped
and started again, which made the backlog worse. Spreading the first connects over time does not bound this
when a start takes longer than the spread; a gate does. The TCP connect itself stays outside the gate: a
machine that is switched off waits on the network, not on the loop, and must not hold a place for seconds.

A machine takes its place once connected and gives it back when born, or when the start fails or is
cancelled; those waiting go in first-come order.
"""

from __future__ import annotations

import asyncio


class StartGate:
    """Shared by every machine of one daemon; `slots` starts run at a time."""

    def __init__(self, slots: int) -> None:
        if slots < 1:
            raise ValueError(f"start gate: expected at least 1 slot, got {slots}")
        self.slots = slots
        self._free = asyncio.Semaphore(slots)
        self.starting = 0  # machines between connect and DBIRTH now
        self.peak = 0  # the most at once (tests read it)

    async def enter(self) -> None:
        await self._free.acquire()
        self.starting += 1
        self.peak = max(self.peak, self.starting)

    def leave(self) -> None:
        self.starting -= 1
        self._free.release()


class StartTicket:
    """One machine's place in the gate (none: never waits); `release` is safe to call when not held."""

    def __init__(self, gate: StartGate | None) -> None:
        self._gate = gate
        self.held = False

    async def acquire(self) -> None:
        if self._gate is None or self.held:
            return
        await self._gate.enter()
        self.held = True

    def release(self) -> None:
        if self._gate is not None and self.held:
            self.held = False
            self._gate.leave()
