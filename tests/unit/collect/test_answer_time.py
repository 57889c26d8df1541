"""A tick is stamped for when the CNC answered, not for when the gateway got round to its answer (issue 25).

At 1,000 machines an answer can wait tens or hundreds of milliseconds for the event loop (the slot's other
machines, a garbage collection); the middle of send-to-handled then lies far after the CNC's answer.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace

import pytest

from edge.collect import plan as pl
from edge.collect import poller as poller_module
from edge.collect.answer_time import AnswerTime
from edge.focas import items as it
from edge.focas.session import ItemResult
from tests.unit.collect.test_tick_changes import ScriptedSession, _ready

WALL_AT_ZERO = 1_700_000_000.0  # the fake wall clock: monotonic 0 is this epoch second


def test_half_the_usual_round_trip_never_more_than_half_this_one() -> None:
    answers = AnswerTime()
    assert answers.half_rtt(0.004) == 0.002
    assert answers.half_rtt(0.200) == 0.002  # the gateway's delay: not the CNC's
    assert answers.half_rtt(0.004) < 0.008  # one late answer barely moved the usual round trip
    assert answers.half_rtt(0.002) == 0.001  # a quicker one is always believed
    for _ in range(60):
        answers.half_rtt(0.020)
    assert answers.half_rtt(0.020) == pytest.approx(0.010, rel=0.05)  # the CNC got slower: followed
    answers.reset()
    assert answers.half_rtt(0.050) == 0.025


class TimedSession(ScriptedSession):
    """Each batch takes the next of `rtts` on the fake clock (the answer handled that much after the send)."""

    def __init__(self, clock: SimpleNamespace) -> None:
        super().__init__()
        self.clock = clock
        self.rtts: list[float] = []

    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        self.clock.now += self.rtts.pop(0)
        return await super()._batch(items)


async def test_an_answer_handled_late_is_stamped_for_when_the_cnc_answered(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    clock = SimpleNamespace(now=100.0)
    monkeypatch.setattr(poller_module, "time", SimpleNamespace(monotonic=lambda: clock.now,
                                                               time=lambda: WALL_AT_ZERO + clock.now))
    poller, _, plan = await _ready(tmp_path)
    session = TimedSession(clock)
    session._connected = True
    poller.session = session
    session.rtts = [0.004, 0.004, 0.004, 0.300]
    stamps: list[tuple[float, int]] = []
    for _ in range(4):
        sent = clock.now
        tick = await poller._tick(plan, frozenset({pl.Group.MACROS}))
        stamps.append((sent, tick.samples[0].timestamp_ms))
        session.macros = [m + 1 if m is not None else None for m in session.macros]  # every tick publishes
        clock.now += 1.0
    sent, stamp = stamps[-1]
    # Handled 300 ms after the send: the middle would stamp it 150 ms after; the CNC answered ~2 ms after.
    assert stamp == round((WALL_AT_ZERO + sent + 0.002) * 1000)
    first_sent, first_stamp = stamps[0]
    assert first_stamp == round((WALL_AT_ZERO + first_sent + 0.002) * 1000)  # a usual tick: its middle
