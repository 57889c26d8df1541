"""The shared request-deadline wheel: never early, at most one step late, one timer per slot, and a
cancellation from outside is never taken for a timeout (nor swallowed) by a session."""

from __future__ import annotations

import asyncio
import gc

import pytest

from edge.focas import deadline as dl
from edge.focas.deadline import Deadline, DeadlineWheel, wheel_for
from edge.focas.errors import FocasTimeout
from edge.focas.model import Capabilities, SysInfo
from edge.focas.session import CncSession


async def _hang() -> None:
    await asyncio.Event().wait()


async def test_an_expired_deadline_cancels_the_task_never_early_at_most_a_step_late() -> None:
    loop = asyncio.get_running_loop()
    wheel = DeadlineWheel(loop, step_s=0.02)
    task = asyncio.create_task(_hang())
    deadline = Deadline()
    armed_at = loop.time()
    wheel.arm(deadline, task, 0.05)  # type: ignore[arg-type]
    with pytest.raises(asyncio.CancelledError):
        await task
    late = loop.time() - (armed_at + 0.05)
    assert deadline.expired
    assert late >= -1e-3  # the loop's own timer resolution
    assert late < 0.02 + 0.2  # one step, plus a loaded machine's scheduling delay
    assert wheel.pending_slots == 0


async def test_a_disarmed_deadline_cancels_nothing() -> None:
    loop = asyncio.get_running_loop()
    wheel = DeadlineWheel(loop, step_s=0.01)
    task = asyncio.create_task(_hang())
    deadline = Deadline()
    wheel.arm(deadline, task, 0.02)  # type: ignore[arg-type]
    wheel.disarm(deadline)
    fired = loop.create_future()
    loop.call_later(0.06, fired.set_result, None)  # well past the slot's timer
    await fired
    assert not task.done() and not deadline.expired
    task.cancel()


async def test_requests_of_many_sessions_share_one_timer_per_slot() -> None:
    loop = asyncio.get_running_loop()
    wheel = DeadlineWheel(loop, step_s=10.0)
    tasks = [asyncio.create_task(_hang()) for _ in range(200)]
    deadlines = [Deadline() for _ in tasks]
    before = len(loop._scheduled)  # type: ignore[attr-defined]
    for deadline, task in zip(deadlines, tasks, strict=True):
        wheel.arm(deadline, task, 5.0)  # type: ignore[arg-type]
    assert wheel.pending_slots <= 2  # now + 5 s falls in one slot of 10 s (two if it straddles a bound)
    assert len(loop._scheduled) - before == wheel.pending_slots  # type: ignore[attr-defined]
    for deadline in deadlines:
        wheel.disarm(deadline)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


async def test_arming_twice_is_a_programming_error() -> None:
    wheel = DeadlineWheel(asyncio.get_running_loop())
    task = asyncio.create_task(_hang())
    deadline = Deadline()
    wheel.arm(deadline, task, 1.0)  # type: ignore[arg-type]
    with pytest.raises(RuntimeError, match="already armed"):
        wheel.arm(deadline, task, 1.0)  # type: ignore[arg-type]
    wheel.disarm(deadline)
    task.cancel()


def test_a_loop_has_one_wheel_and_it_goes_with_the_loop() -> None:
    loop = asyncio.new_event_loop()
    try:
        assert wheel_for(loop) is wheel_for(loop)
    finally:
        loop.close()
    del loop
    gc.collect()
    assert not any(not known.is_closed() for known in dl._WHEELS)  # the closed loop left the registry


def test_a_zero_step_is_refused() -> None:
    loop = asyncio.new_event_loop()
    try:
        with pytest.raises(ValueError, match="step must be > 0"):
            DeadlineWheel(loop, step_s=0)
    finally:
        loop.close()


class _SilentSession(CncSession):
    """A session whose reads never answer: only the deadline can end them."""

    transport = "silent"

    def __init__(self, timeout: float) -> None:
        super().__init__(timeout=timeout)
        self._connected = True
        self.resets = 0

    async def _open(self) -> SysInfo:  # pragma: no cover - not used
        raise NotImplementedError

    async def _close(self) -> None:
        self.resets += 1

    async def _batch(self, items):  # type: ignore[no-untyped-def]
        await _hang()

    async def _write_macro(self, number: int, value: float) -> None:
        await _hang()

    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:  # pragma: no cover
        await _hang()

    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None:  # pragma: no cover
        await _hang()

    @property
    def capabilities(self) -> Capabilities:  # pragma: no cover - not used
        return Capabilities(self.transport, frozenset())


async def test_a_silent_control_times_out_and_the_session_resets() -> None:
    session = _SilentSession(timeout=0.1)
    with pytest.raises(FocasTimeout, match=r"no complete answer within 0\.1s"):
        await session.read_status()
    assert session.resets == 1 and not session.connected
    session._connected = True
    with pytest.raises(FocasTimeout):
        await session.write_macro(500, 1.0)  # writes are guarded the same way


async def test_a_cancellation_from_outside_stays_a_cancellation() -> None:
    session = _SilentSession(timeout=30.0)
    task = asyncio.create_task(session.read_status())
    await asyncio.sleep(0)  # let it start and arm its deadline
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert session.resets == 0  # not handled as a timeout


async def test_a_cancellation_racing_the_deadline_is_not_swallowed() -> None:
    """The wheel and a shutdown both cancel the task before it runs again: the shutdown wins."""
    session = _SilentSession(timeout=0.01)
    task = asyncio.create_task(session.read_status())
    await asyncio.sleep(0)
    wheel = session._wheel
    assert wheel is not None
    for slot in list(wheel._slots):
        wheel._fire(slot)  # the deadline fires ...
    task.cancel()  # ... and, in the same loop turn, the shutdown
    with pytest.raises(asyncio.CancelledError):
        await task
