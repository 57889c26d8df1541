"""The replay keeps its pace over the whole backlog, even when every step's barrier takes time.

A fake clock: the replay's sleeps and the barrier's wait for a PUBACK advance it, nothing else does, so
the replay's duration is counted, not timed.
"""

from __future__ import annotations

import asyncio
import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

import pytest

from edge.publish import replay
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.node import Outgoing
from edge.publish.replay import Replayer
from edge.publish.spool_rows import SpoolEntry
from edge.publish.tasks import BackgroundTasks
from edge.samples import MetricType, Quality, Sample

ROWS = 1000
RATE = 1000.0  # rows per second: the backlog is due after 1.0 s
BARRIER_S = 0.05  # each step's PUBACK comes this late
_yield = asyncio.sleep  # the real one: the test replaces asyncio.sleep by the clock's


class Clock:
    def __init__(self, turn_s: float = 0.0, row_s: float = 0.0) -> None:
        self.now = 0.0
        self.yields = 0
        self.turn_s = turn_s  # what a yield costs: the live ticks' share of one event-loop turn
        self.row_s = row_s  # the replay's work per row

    def monotonic(self) -> float:
        return self.now

    async def sleep(self, delay: float) -> None:
        self.now += max(0.0, delay) + self.turn_s
        self.yields += 1
        await _yield(0)


class Conn:
    connected = True
    held = 0  # the socket takes every byte at once


class Link:
    fmt = "sparkplug"
    session = 1
    suspect = False

    def __init__(self, clock: Clock) -> None:
        self.conn = Conn()
        self.policy = ForwardingPolicy(replay_rows_per_s=RATE, replay_batch=50)
        self.clock = clock
        self.sent = 0
        self.barriers = 0

    def send(self, conn: Any, messages: Sequence[Outgoing]) -> bool:
        self.sent += len(messages)
        self.clock.now += self.clock.row_s * len(messages)
        return True

    def suspect_dead(self, conn: Any, reason: str) -> None:
        raise AssertionError(reason)

    async def barrier(self, conn: Any) -> bool:
        self.barriers += 1
        await self.clock.sleep(BARRIER_S)
        return True


class Target:
    def replay_ready(self) -> bool:
        return True

    def replay_devices(self) -> list[str] | None:
        return None

    def replay_accepts(self, device_id: str) -> bool:
        return True

    def historical(self, entry: Any, samples: Sequence[Sample]) -> list[Outgoing]:
        return [Outgoing(f"t/{entry.device_id}", b"x", 0, False)]


class Spool:
    def __init__(self) -> None:
        sample = Sample("x", 1, MetricType.INT32, 0, Quality.GOOD, False)
        self.rows = [SpoolEntry(i, "sparkplug", "m1", "data", [sample]) for i in range(1, ROWS + 1)]

    def hold(self, *args: Any) -> None:
        raise AssertionError("nothing is held during this replay")

    def oldest(self, fmt: str, limit: int, devices: Any = None, lazy: bool = False,
               after: int = 0) -> list[SpoolEntry]:
        return [r for r in self.rows if r.id > after][:limit]

    def ack(self, ids: Sequence[int]) -> None:
        acked = set(ids)
        self.rows = [r for r in self.rows if r.id not in acked]

    def pending(self, fmt: str | None = None) -> int:
        return len(self.rows)


async def _replay(clock: Clock) -> tuple[Link, Spool]:
    link, spool = Link(clock), Spool()
    tasks = BackgroundTasks()
    replayer = Replayer(link, Target(), spool, Counter(), tasks)  # type: ignore[arg-type]
    replayer.kick()
    for _ in range(100_000):
        await _yield(0)
        if not replayer._replaying:
            break
    return link, spool


def test_replay_holds_its_rate_across_steps_whose_barrier_is_slow(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = Clock()
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    link, spool = asyncio.run(_replay(clock))
    assert spool.rows == [] and link.sent == ROWS
    steps = link.barriers
    assert steps == ROWS // int(RATE * replay.FETCH_EACH_S)  # the test's target sends each row alone
    # Paced per step, every barrier came on top: 1.0 s + 10 x 0.05 s. Paced over the whole replay, the
    # barriers eat into the sleeps: only the last one is left over.
    assert clock.now <= ROWS / RATE + BARRIER_S + 1e-6
    assert clock.now >= ROWS / RATE - 1e-6  # and never faster than the pace


def test_replay_behind_its_pace_yields_per_slice_of_work_not_per_chunk(monkeypatch: pytest.MonkeyPatch) -> None:
    """A large fleet's live ticks make every yield cost an event-loop turn far longer than a chunk's work
    (1,000 machines: ~70 rows/s when yielding after each chunk of 50). Behind its pace (each turn here
    costs 100 ms, the rows are due 1 ms apart: after its first sleep the replay never catches up), the
    replay yields once per SLICE_S of work and at each step's barrier, not after every chunk."""
    clock = Clock(turn_s=0.1, row_s=0.0002)
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    link, spool = asyncio.run(_replay(clock))
    assert spool.rows == [] and link.sent == ROWS
    per_step = 2  # the step's final pace and the barrier's wait for its PUBACK
    slices = math.ceil(ROWS * clock.row_s / replay.SLICE_S)
    assert clock.yields <= per_step * link.barriers + slices + 1
    assert clock.yields < ROWS // link.policy.replay_batch + per_step * link.barriers  # per chunk: 40


def test_behind_its_pace_the_replay_takes_a_slice_as_long_as_the_live_turn(monkeypatch: pytest.MonkeyPatch) -> None:
    """When a live turn takes 100 ms, a 20 ms slice gives the replay a sixth of the loop (1,000 machines:
    5x the live rate against the 12x asked for); a slice as long as the turn (up to MAX_SLICE_S) gives it
    about half: a yield per MAX_SLICE_S of work, not per SLICE_S."""
    clock = Clock(turn_s=replay.MAX_SLICE_S, row_s=0.0003)
    monkeypatch.setattr(replay, "FETCH_EACH_S", replay.FETCH_S)  # steps of Sparkplug's length: few step yields
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    link, spool = asyncio.run(_replay(clock))
    assert spool.rows == [] and link.sent == ROWS
    per_step = 2  # the step's final pace and the barrier's wait for its PUBACK
    work = ROWS * clock.row_s
    assert clock.yields <= per_step * link.barriers + math.ceil(work / replay.MAX_SLICE_S) + 2
    assert clock.yields < math.ceil(work / replay.SLICE_S)


def _work_per_slice(clock: Clock, work_s: float = 0.01, slices: int = 3) -> list[float]:
    """A pacer behind its pace (rows due at once) doing `work_s` of work between chunk boundaries: the work
    it did between its yields, for `slices` yields after the first."""
    pacer = replay._Pacer(clock.now, rate=1e9, chunk=1)

    async def run() -> list[float]:
        await pacer.pace(force=True)  # the first yield: the loop is away for one live turn
        done: list[float] = []
        worked = 0.0
        while len(done) < slices:
            clock.now += work_s
            worked += work_s
            pacer.counted(1)
            if await pacer.pace():
                done.append(round(worked, 6))
                worked = 0.0
        return done

    return asyncio.run(run())


@pytest.mark.parametrize(("turn_s", "slice_s"), [
    (0.005, replay.SLICE_S),  # a short live turn: the least slice, not one chunk
    (0.3, 0.3),  # a live turn longer than 0.1 s (1,000 machines on a slow host): a slice as long
    (2.0, 0.5),  # a turn longer than half a 1 Hz tick's period: that half period
])
def test_behind_its_pace_the_replay_keeps_the_loop_as_long_as_the_live_turn_up_to_half_a_1_hz_period(
        monkeypatch: pytest.MonkeyPatch, turn_s: float, slice_s: float) -> None:
    """Behind its pace the replay gets about half the loop: after a yield whose live turn took `turn_s`,
    it works that long before it yields again (a fixed 0.1 s bound gave it a quarter of the loop or less
    where 1,000 machines' live turn was 0.3 s: 1.2x the live rate, not 10x), but never longer than half
    the period of a 1 Hz tick, which then still completes within its period."""
    clock = Clock(turn_s=turn_s)
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    assert _work_per_slice(clock) == [pytest.approx(slice_s, abs=0.0101)] * 3


class HeldBarriers(Link):
    """A broker whose PUBACKs come only when the test releases them, oldest first."""

    def __init__(self, clock: Clock) -> None:
        super().__init__(clock)
        self.waiting: list[asyncio.Future[bool]] = []

    async def barrier(self, conn: Any) -> bool:
        self.barriers += 1
        answer: asyncio.Future[bool] = asyncio.get_running_loop().create_future()
        self.waiting.append(answer)
        return await answer

    def in_flight(self) -> int:
        return sum(not answer.done() for answer in self.waiting)


async def _settle() -> None:
    for _ in range(200):
        await _yield(0)


def test_several_steps_go_out_before_the_first_barrier_returns_and_rows_leave_only_with_their_barrier(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A slow PUBACK does not stop the replay at the next step: up to IN_FLIGHT steps are out, unconfirmed;
    a step's rows leave the spool when its own barrier comes back, never before, and a step more goes out."""
    clock = Clock()
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    step = int(RATE * replay.FETCH_EACH_S)

    async def scenario() -> None:
        link, spool = HeldBarriers(clock), Spool()
        replayer = Replayer(link, Target(), spool, Counter(), BackgroundTasks())  # type: ignore[arg-type]
        replayer.kick()
        await _settle()
        assert link.in_flight() == replay.IN_FLIGHT and link.sent == replay.IN_FLIGHT * step
        assert len(spool.rows) == ROWS  # nothing confirmed, nothing acknowledged
        link.waiting[0].set_result(True)
        await _settle()
        assert [r.id for r in spool.rows][:1] == [step + 1]  # the first step's rows only
        assert link.in_flight() == replay.IN_FLIGHT and link.sent == (replay.IN_FLIGHT + 1) * step
        while replayer._replaying:
            for answer in link.waiting:
                if not answer.done():
                    answer.set_result(True)
            await _settle()
        assert spool.rows == [] and link.sent == ROWS

    asyncio.run(scenario())


class SlowSocket(Conn):
    """The kernel takes the client's bytes only when the replay waits for room."""

    def __init__(self) -> None:
        self.held = 0
        self.most = 0
        self.waits: list[int] = []

    async def wait_for_room(self, limit: int) -> None:
        self.waits.append(limit)
        self.held = 0
        await _yield(0)


def test_the_replay_waits_while_the_mqtt_client_holds_more_than_its_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """A broker slower than the pace: the bytes the socket has not taken stay within HELD_BYTES and a
    chunk, instead of a step's worth (JSON's 0.5 s steps queued ~12,000 messages in paho)."""
    clock = Clock()
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    bound = 120
    monkeypatch.setattr(replay, "HELD_BYTES", bound)
    message = len(b"x")

    async def scenario() -> tuple[Link, Spool, SlowSocket]:
        link, spool = Link(clock), Spool()
        socket = SlowSocket()
        link.conn = socket
        sent = link.send

        def send(conn: Any, messages: Sequence[Outgoing]) -> bool:
            socket.held += message * len(messages)
            socket.most = max(socket.most, socket.held)
            return sent(conn, messages)

        link.send = send  # type: ignore[method-assign]
        replayer = Replayer(link, Target(), spool, Counter(), BackgroundTasks())  # type: ignore[arg-type]
        replayer.kick()
        while replayer._replaying:
            await _yield(0)
        return link, spool, socket

    link, spool, socket = asyncio.run(scenario())
    assert spool.rows == [] and link.sent == ROWS
    assert socket.waits and set(socket.waits) == {bound // 2}
    assert socket.most <= bound + link.policy.replay_batch * message


def test_a_replay_that_empties_the_spool_calls_its_after_replay_hook_and_one_cut_short_does_not(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The daemon gives the C heap's free pages back after a replay (edge.service.heap_trim): once the spool
    is empty, not while rows wait for the next session."""
    clock = Clock()
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)

    async def scenario(cut_short: bool) -> tuple[list[int], Spool]:
        link, spool = HeldBarriers(clock), Spool()
        replayer = Replayer(link, Target(), spool, Counter(), BackgroundTasks())  # type: ignore[arg-type]
        calls: list[int] = []
        replayer.after_replay = lambda: calls.append(len(spool.rows))
        replayer.kick()
        await _settle()
        link.waiting[0].set_result(True)
        await _settle()
        if cut_short:
            link.session += 1  # the connection went: the steps in flight stay in the spool
        while replayer._replaying:
            for answer in link.waiting:
                if not answer.done():
                    answer.set_result(True)
            await _settle()
        return calls, spool

    calls, spool = asyncio.run(scenario(cut_short=False))
    assert spool.rows == [] and calls == [0]
    calls, spool = asyncio.run(scenario(cut_short=True))
    assert spool.rows and calls == []


def test_a_replay_logs_where_its_time_went(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """The end log says how a replay's time was spent: its yields behind the pace and the loop's other work
    while it waited (the live turns: the longest tells whether MAX_SLICE_S binds), sleeps ahead of the
    pace, waits for the MQTT client's room and for barriers. On a slow host it told a replay that is
    CPU-bound (live turns <= 0.14 s, no waits) from one held back by its slice (docs/performance.md)."""
    clock = Clock(turn_s=0.1, row_s=0.003)  # 3 s of work for rows due over 1 s: behind the pace throughout
    monkeypatch.setattr(replay, "FETCH_EACH_S", replay.FETCH_S)
    monkeypatch.setattr(replay.time, "monotonic", clock.monotonic)
    monkeypatch.setattr(replay.asyncio, "sleep", clock.sleep)
    with caplog.at_level("INFO", logger="edge.publish.replay"):
        link, spool = asyncio.run(_replay(clock))
    assert spool.rows == [] and link.sent == ROWS
    ended = [r.getMessage() for r in caplog.records if r.getMessage().startswith("spool replayed")]
    assert len(ended) == 1
    fields = dict(part.split("=") for part in ended[0].split()[2:])
    assert fields["rows"] == str(ROWS) and fields["left"] == "0"
    yields = int(fields["yields"])
    assert 0 < yields < clock.yields  # the barriers' waits are not the pace's yields
    # each yield lets one live turn run (and a barrier's wait, on this fake clock, may fall into it)
    assert yields * clock.turn_s - 0.05 <= float(fields["away_s"]) <= yields * (clock.turn_s + BARRIER_S) + 0.05
    assert float(fields["max_away_s"]) >= clock.turn_s - 0.005
    assert float(fields["ahead_s"]) == 0.0  # never ahead of its pace: no sleep
    assert float(fields["room_s"]) == 0.0  # the socket takes every byte at once
    # the replay, its own work and its waits: the fields account for its seconds
    assert float(fields["seconds"]) == pytest.approx(clock.now, abs=0.05)
