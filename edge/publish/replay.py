"""Replaying the spool after a reconnect: oldest first, paced, as historical messages.

The pace is replay_live_factor (18) times the rate the rows were spooled at, at least replay_rows_per_s: a
backlog clears in a tenth of the outage that made it, and the live ticks get the loop between chunks.
Sparkplug sends a step's rows of one device (~9 at that pace) in one DDATA, every metric is_historical with
its own timestamp (what the spec's is_historical is for: "batching, store and forward"), encoded from the
parsed rows without a Sample per value; JSON sends a message per value.

Runs while live data flows. A batch of rows is acknowledged (deleted from the spool) only after a delivery
barrier on the same connection (edge.publish.link), so a crash or a lost connection during a replay sends
the rows again: at-least-once. For Sparkplug, what the host already has (births, live batches spooled
behind a hold, rows an earlier replay sent) is skipped (edge.publish.replay_dedupe).

A `Replayer` serves one format; the format's session is its `ReplayTarget` (when to replay, which devices,
how a row becomes historical messages).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from operator import attrgetter
from typing import Any, Protocol

from edge.publish.holding import Format, IndexedSpool, ReplaySpool, Spool
from edge.publish.link import DeliveryLink
from edge.publish.mqtt import MqttConnection
from edge.publish.node import Outgoing
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.spool_rows import TIMESTAMP
from edge.publish.tasks import BackgroundTasks
from edge.samples import Sample

log = logging.getLogger(__name__)
_historical_of = attrgetter("historical")

# A replay step fetches (and confirms with one barrier) about this many seconds of rows: at 18x the live rate
# that is ~9 s of spooled ticks, so Sparkplug sends a device's ~9 rows of a step in one DDATA.
FETCH_S = 0.5
# A replay sending one message per value (JSON) fetches less: its step's messages wait in the MQTT client's
# queue until the socket takes them, and 0.5 s of them (12 values a row) held ~15 MB at 20 machines in the soak.
FETCH_EACH_S = 0.1
# Steps whose barrier has not come back yet, at most (the oldest is awaited before another goes out).
IN_FLIGHT = 3
# The replay waits while the MQTT connection holds more than this many bytes for the broker (not yet taken by
# the kernel, or QoS 1 not yet acknowledged): a broker slower than the pace then slows the replay instead of
# filling the process's memory.
HELD_BYTES = 1024 * 1024
READ_ROWS = 256  # Sparkplug reads a step's bodies about this many rows (whole devices) at a time
MERGE_ROWS = 16  # spool rows of one device in one replayed DDATA at most (~5 kB at 12 values a row)
SLICE_S = 0.02  # behind its pace, a replay yields to live ticks after this much work at least, not each chunk
# and after this much at most: half the period of the 1 Hz ticks a fleet whose live turns grow this long polls
# at, so a live tick, waiting a slice and its own turn, still completes within its period (`_Pacer`)
MAX_SLICE_S = 0.5


class ReplayTarget(Protocol):
    """The format side of a replay."""

    def replay_ready(self) -> bool:
        """Rows may go out now (Sparkplug: born and no rebirth pending)."""
        ...

    def replay_devices(self) -> list[str] | None:
        """The devices whose rows may go out (None: all)."""
        ...

    def replay_accepts(self, device_id: str) -> bool:
        """This device's rows may still go out (it may have gone offline since the query)."""
        ...

    def historical(self, entry: Any, samples: Sequence[Sample]) -> list[Outgoing]:
        """The messages of one spool row (`samples`, already marked historical). A target may also have
        `historical_rows(entry, rows)`: the same from the row's parsed JSON rows (edge.publish.spool_rows)."""
        ...


class Replayer:
    """Replays one format's spooled rows over its link; at most one replay runs at a time."""

    def __init__(self, link: DeliveryLink, target: ReplayTarget, spool: Spool, counters: Counter[str],
                 tasks: BackgroundTasks, delivered: DeliveredValues | None = None) -> None:
        self._link = link
        self._target = target
        self._spool = spool
        self._counters = counters
        self._tasks = tasks
        self._delivered = delivered  # Sparkplug only: skip what the host has
        self._from_rows = getattr(target, "historical_rows", None)  # Sparkplug: parsed rows to messages
        self._replaying = False
        self._again = False  # a kick came while replaying: look for rows once more before ending
        # Called when a replay has emptied the spool (the daemon gives the C heap's free pages back then).
        self.after_replay: Callable[[], object] | None = None

    def kick(self) -> None:
        """Start replaying the spool (or make the running replay look again)."""
        if self._tasks.stopping or not isinstance(self._spool, ReplaySpool):
            return
        if self._replaying:
            self._again = True
            return
        conn = self._link.conn
        if conn is None:
            return
        self._replaying = True
        self._again = False
        self._tasks.spawn(self._replay(conn, self._link.session))

    def drain_waiting_rows(self) -> None:
        """Rows still waiting with no replay running (a replay that failed, a spool that had no room to
        delete): replay them now, not at the next reconnect."""
        spool = self._spool
        if self._replaying or not isinstance(spool, ReplaySpool) or not self._target.replay_ready():
            return
        if spool.pending(self._link.fmt):
            self.kick()

    async def _replay(self, conn: MqttConnection, session: int) -> None:
        try:
            await self._replay_rows(conn, session)
        except Exception as exc:  # the spool failed: the rows stay and the probe loop kicks a new replay
            self._counters["replay_errors"] += 1
            log.error("spool replay failed, retried within a probe interval format=%s error=%s",
                      self._link.fmt, exc)
        finally:
            self._replaying = False

    async def _replay_rows(self, conn: MqttConnection, session: int) -> None:
        """Oldest first, paced, as historical messages; rows acked after a barrier."""
        spool = self._spool
        assert isinstance(spool, ReplaySpool)
        link, target, delivered, fmt = self._link, self._target, self._delivered, self._link.fmt
        rate = self._rate(spool, fmt)
        fetch_s = FETCH_S if self._from_rows is not None else FETCH_EACH_S
        fetch = max(link.policy.replay_batch, int(rate * fetch_s))  # rows per query and per barrier
        started = time.monotonic()
        sent_rows = 0
        pacer = _Pacer(started, rate, link.policy.replay_batch)
        waiting = spool.pending(fmt)
        if waiting:
            log.info("spool replay started format=%s rows=%d rows_per_s=%.0f", fmt, waiting, rate)

        def current() -> bool:
            return (session == link.session and conn.connected and not link.suspect
                    and not self._tasks.stopping and target.replay_ready())

        async def confirmed(barrier: asyncio.Future[bool], step: _Step) -> bool:
            """The step's barrier came back: its rows reached the broker and leave the spool."""
            nonlocal sent_rows
            waited = time.monotonic()
            ok = await barrier
            pacer.barrier_s += time.monotonic() - waited
            if not ok:
                return False
            spool.ack(step.done)
            if delivered is not None:
                for entry in step.with_samples:  # rows sent without samples had no value the record knew
                    delivered.discard(entry.device_id, entry.samples)
                delivered.forget_rows(step.done)
            self._counters["replayed_rows"] += len(step.done)
            sent_rows += len(step.done)
            return True

        # Up to IN_FLIGHT steps' barriers in flight while the next step goes out: a PUBACK from a busy broker
        # takes a good part of a step (~40 % of the replay's time at 1,000 machines when each step waited for
        # its own). What is in flight costs no memory here: the steps' bytes wait in the kernel and the
        # broker, not in the MQTT client (`_room`), and a step in flight keeps only its row ids.
        window: deque[tuple[asyncio.Future[bool], _Step]] = deque()
        after = 0  # the rows up to here are sent (and in flight or acked)
        streamed = self._from_rows is not None and isinstance(spool, IndexedSpool)
        by_device: dict[str, list[int]] = {}
        entries: Sequence[Any] = []
        try:
            while current():
                while window and (window[0][0].done() or len(window) >= IN_FLIGHT):
                    if not await confirmed(*window.popleft()):
                        return
                if not current():
                    return
                if streamed:  # ids only; the bodies are read a few devices at a time (`_send_streamed`)
                    assert isinstance(spool, IndexedSpool)
                    by_device = spool.oldest_ids(fmt, fetch, target.replay_devices(), after=after)
                    last = max((ids[-1] for ids in by_device.values()), default=None)
                else:
                    entries = spool.oldest(fmt, fetch, target.replay_devices(), lazy=self._from_rows is not None,
                                           after=after)
                    last = entries[-1].id if entries else None
                if last is None:
                    if window:
                        if not await confirmed(*window.popleft()):
                            return
                        continue
                    if self._again:  # a device born meanwhile may have rows before `after`
                        self._again = False
                        after = 0
                        continue
                    break
                after = last
                step = _Step(conn, current)
                if streamed:
                    ok = await self._send_streamed(step, by_device, pacer)
                    by_device = {}
                elif self._from_rows is not None:
                    ok = await self._send_by_device(step, entries, pacer)
                else:
                    ok = await self._send_each(step, entries, pacer)
                entries = []  # not alive while the next step is read
                if not ok:
                    return
                await pacer.pace(force=True)
                if not current():
                    return
                window.append((asyncio.ensure_future(link.barrier(conn)), step))
        finally:
            for barrier, _ in window:
                barrier.cancel()  # the session ended: their rows stay in the spool
        left = spool.pending(fmt)
        if delivered is not None and not left:
            delivered.forget()
        if sent_rows:
            log.info("spool replayed format=%s rows=%d seconds=%.1f left=%d rows_per_s=%.0f %s", fmt, sent_rows,
                     time.monotonic() - started, left, rate, pacer.summary())
            if not left and self.after_replay is not None:
                self.after_replay()

    def _due(self, step: _Step, entry: Any) -> bool:
        """The entry is this step's to send: its device is still born and no earlier replay sent it (then
        it is only acknowledged)."""
        if not self._target.replay_accepts(entry.device_id):
            return False  # went offline since the query: its rows wait for its next DBIRTH
        step.done.append(entry.id)
        return self._delivered is None or not self._delivered.has_row(entry.id)

    async def _send_each(self, step: _Step, entries: Sequence[Any], pacer: _Pacer) -> bool:
        """Each row as its own messages (JSON: a message per value); False when the replay must stop."""
        for entry in entries:
            if self._due(step, entry) and not self._send_samples(step, entry):
                return False
            if pacer.counted(1):
                await self._pace(step, pacer)
        return True

    async def _send_streamed(self, step: _Step, by_device: dict[str, list[int]], pacer: _Pacer) -> bool:
        """A step's rows, by device (`_send_by_device`), their bodies read READ_ROWS rows' worth of devices
        at a time: the step's ids are small, its ~9 MB of bodies are not alive at once."""
        spool = self._spool
        assert isinstance(spool, IndexedSpool)
        fmt = self._link.fmt
        chunk: list[int] = []
        for ids in by_device.values():
            chunk.extend(ids)
            if len(chunk) >= READ_ROWS:
                chunk.sort()
                if not await self._send_by_device(step, spool.read(fmt, chunk), pacer):
                    return False
                chunk = []
        if chunk:
            chunk.sort()
            return await self._send_by_device(step, spool.read(fmt, chunk), pacer)
        return True

    async def _send_by_device(self, step: _Step, entries: Sequence[Any], pacer: _Pacer) -> bool:
        """Sparkplug: a step's rows of one device, oldest first, in DDATA of up to MERGE_ROWS rows each,
        straight from their parsed rows, without the values a birth carried. A row whose values a recorded
        key may match goes through the dedupe on its own, as samples, after the rows before it (so each
        device's rows still go out in spool order)."""
        delivered = self._delivered
        groups: dict[str, list[Any]] = {}
        for entry in entries:
            if self._due(step, entry):
                groups.setdefault(entry.device_id, []).append(entry)
        for device_id, group in groups.items():
            for start in range(0, len(group), MERGE_ROWS):
                part = group[start:start + MERGE_ROWS]
                merged: list[tuple[Any, list[Any]]] = []
                for entry in part:
                    rows = entry.rows()
                    if rows is not None and delivered is not None \
                            and delivered.overlaps(device_id, map(TIMESTAMP, rows)):
                        rows = delivered.fresh_rows(device_id, rows)  # None: keys may match, decide on samples
                        if rows is not None and not rows:
                            continue  # every value went out in a birth: acknowledged with the step, not sent
                    if rows is not None:
                        merged.append((entry, rows))
                        continue
                    if not (self._send_rows(step, merged) and self._send_samples(step, entry)):
                        return False
                    merged = []
                if not self._send_rows(step, merged):
                    return False
                if pacer.counted(len(part)):
                    await self._pace(step, pacer)
        return True

    def _send_rows(self, step: _Step, merged: list[tuple[Any, list[Any]]]) -> bool:
        """One DDATA of these rows of one device; rows that are not as written go one by one, as samples
        if need be (decode_samples' leniency), or are dropped as unreadable."""
        if not merged:
            return True
        assert self._from_rows is not None
        try:
            messages = self._from_rows(merged[0][0], [row for _, rows in merged for row in rows])
        except (TypeError, ValueError):
            if len(merged) > 1:
                return all(self._send_rows(step, [pair]) for pair in merged)
            return self._send_samples(step, merged[0][0])
        if not self._send(step, messages):
            return False
        if self._delivered is not None and messages:
            for entry, _ in merged:
                self._delivered.record_row(entry.id)
        return True

    def _send_samples(self, step: _Step, entry: Any) -> bool:
        """A row as samples: what the host has left out (Sparkplug), the rest marked historical."""
        try:
            samples = entry.samples
        except (TypeError, ValueError) as exc:  # not a row: it would block the replay forever
            step.done.remove(entry.id)
            getattr(self._spool, "unreadable", _ignore)(entry.id, exc)
            return True
        delivered = self._delivered
        if delivered is not None:
            samples = delivered.fresh(entry.device_id, samples)
        self._counters["replayed_rows_as_samples"] += 1  # the slow path: a row whose values the host may have
        if not samples:
            return True
        if not all(map(_historical_of, samples)):  # the spool hands them out historical already
            samples = [s if s.historical else _as_historical(s) for s in samples]
        messages = self._target.historical(entry, samples)
        if not self._send(step, messages):
            return False
        if delivered is not None and messages:
            delivered.record_row(entry.id)
            step.with_samples.append(entry)
        return True

    @staticmethod
    async def _pace(step: _Step, pacer: _Pacer) -> None:
        """At a chunk boundary: keep to the pace, and wait while the MQTT connection holds more than
        HELD_BYTES for the broker (it is slower than the pace)."""
        if step.conn.held > HELD_BYTES:
            waited = time.monotonic()
            await step.conn.wait_for_room(HELD_BYTES // 2)
            pacer.room_s += time.monotonic() - waited
            pacer.resumed()
        await pacer.pace()

    def _send(self, step: _Step, messages: Sequence[Outgoing]) -> bool:
        link = self._link
        for m in messages:
            if not step.current():
                return False
            if not link.send(step.conn, (m,)):
                link.suspect_dead(step.conn, "replay publish refused by the MQTT client")
                return False
            self._counters["replayed_messages"] += 1
        return True

    def _rate(self, spool: ReplaySpool, fmt: Format) -> float:
        """Rows per second: the policy's least rate, or replay_live_factor times the rate the rows were
        spooled at (what the fleet produced while the broker was away), whichever is higher."""
        policy = self._link.policy
        spooled = getattr(spool, "spooled_rate", None)
        live = spooled(fmt) if spooled is not None else None
        return max(policy.replay_rows_per_s, policy.replay_live_factor * live) if live else policy.replay_rows_per_s

class _Step:
    """One replay step: its connection, whether the replay may go on, the rows it covers (acked after its
    barrier) and those sent as samples (their values leave the dedupe's record with the ack)."""

    def __init__(self, conn: MqttConnection, current: Callable[[], bool]) -> None:
        self.conn = conn
        self.current = current
        self.done: list[int] = []
        self.with_samples: list[Any] = []


def _ignore(*args: object) -> None:
    return None


class _Pacer:
    """Holds a replay to its rate, counted from the replay's start (not per chunk): the query, the barrier
    and the delete of every step eat into the sleeps, not into the rate (paced per chunk, those took ~25 %
    of a step on top, and a 12x pace delivered 9x).

    Behind the pace, a yield costs a whole event-loop turn, which under the live load of a large fleet is
    far longer than a chunk's work (1,000 machines: ~0.5 s a turn, one chunk of 50 rows each, ~90 rows/s). So, behind
    the pace, the replay keeps the loop for a slice of work before it yields: as long as the loop was away
    at its last yield (the live ticks' turn), at least SLICE_S and at most MAX_SLICE_S. Behind its pace the
    replay so gets about half the loop, however long the live turns grow; a fixed 20 ms slice got it 5x the
    live rate at 1,000 machines, not the 12x asked for (bench outage). The bound is the live ticks' period,
    not what one turn takes on a fast host: capped at 0.1 s, a host whose live turn of 1,000 machines took
    longer gave the replay a quarter of the loop or less (1.2x the live rate, 26 s of 41 s yielding)."""

    def __init__(self, started: float, rate: float, chunk: int) -> None:
        self._started = started
        self._rate = rate
        self._chunk = chunk
        self.rows = 0  # rows handed out since `started`
        self._slice_from = time.monotonic()
        self._slice = SLICE_S
        # where a replay's time went (its end log): yields behind the pace and the loop's other work while it
        # waited, sleeps ahead of the pace, waits for the MQTT client's room and for the steps' barriers
        self.yields = 0
        self.away_s = 0.0
        self.max_away_s = 0.0
        self.ahead_s = 0.0
        self.room_s = 0.0
        self.barrier_s = 0.0

    def counted(self, rows: int) -> bool:
        """Count rows handed out; True when a chunk boundary was passed (time to `pace`)."""
        before = self.rows
        self.rows += rows
        return before // self._chunk != self.rows // self._chunk

    def resumed(self) -> None:
        """The replay gave the loop away (not in `pace`): its slice of work starts again now."""
        self._slice_from = time.monotonic()

    async def pace(self, force: bool = False) -> bool:
        """Sleep if ahead of the pace, yield if the slice is spent (or `force`); True if it gave the loop
        away."""
        now = time.monotonic()
        ahead = self._started + self.rows / self._rate - now
        if ahead <= 0 and not force and now - self._slice_from < self._slice:
            return False
        await asyncio.sleep(max(0.0, ahead))
        self._slice_from = time.monotonic()
        away = self._slice_from - now - max(0.0, ahead)  # the loop's other work while the replay waited
        self._slice = min(MAX_SLICE_S, max(SLICE_S, away))
        self.yields += 1
        self.away_s += away
        self.max_away_s = max(self.max_away_s, away)
        self.ahead_s += max(0.0, ahead)
        return True

    def summary(self) -> str:
        return (f"yields={self.yields} away_s={self.away_s:.1f} max_away_s={self.max_away_s:.2f} "
                f"ahead_s={self.ahead_s:.1f} room_s={self.room_s:.1f} barrier_s={self.barrier_s:.1f}")


def _as_historical(s: Sample) -> Sample:
    """The sample marked historical (built directly: dataclasses.replace costs three times as much)."""
    return Sample(s.name, s.value, s.type, s.timestamp_ms, s.quality, True)
