"""Replaying the spool after a reconnect: oldest first, paced, each row as its own historical message(s).

The pace is replay_live_factor (12) times the rate the rows were spooled at, at least replay_rows_per_s: a
backlog clears in a tenth of the outage that made it, and the live ticks get the loop between chunks.

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
from collections import Counter
from collections.abc import Sequence
from operator import attrgetter
from typing import Any, Protocol

from edge.publish.holding import Format, ReplaySpool, Spool
from edge.publish.link import DeliveryLink
from edge.publish.mqtt import MqttConnection
from edge.publish.node import Outgoing
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.tasks import BackgroundTasks
from edge.samples import Sample

log = logging.getLogger(__name__)
_historical_of = attrgetter("historical")

FETCH_S = 0.1  # a replay step fetches (and confirms with one barrier) about this many seconds of rows
SLICE_S = 0.02  # behind its pace, a replay yields to live ticks after this much work, not after each chunk


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
        """Oldest first, paced, each row as its own historical message(s); rows acked after a barrier."""
        spool = self._spool
        assert isinstance(spool, ReplaySpool)
        link, target, delivered, fmt = self._link, self._target, self._delivered, self._link.fmt
        rate = self._rate(spool, fmt)
        chunk = link.policy.replay_batch
        fetch = max(chunk, int(rate * FETCH_S))  # rows per query and per barrier
        started = time.monotonic()
        sent_rows = 0
        paced = 0  # rows handed out since `started`: the pace is kept over the whole replay, not per step
        pacer = _Pacer(started, rate)

        def current() -> bool:
            return (session == link.session and conn.connected and not link.suspect
                    and not self._tasks.stopping and target.replay_ready())

        while current():
            entries = spool.oldest(fmt, fetch, target.replay_devices(), parsed=True) if self._from_rows \
                else spool.oldest(fmt, fetch, target.replay_devices())
            if not entries:
                if self._again:
                    self._again = False
                    continue
                break
            done: list[int] = []
            for entry in entries:
                if not target.replay_accepts(entry.device_id):
                    continue  # went offline since the query: its rows wait for its next DBIRTH
                done.append(entry.id)
                if delivered is not None and delivered.has_row(entry.id):
                    continue  # an earlier replay sent it: proven, or to be proven by this step's barrier
                try:
                    messages = self._historical_messages(entry)
                except _Unreadable as exc:
                    done.pop()
                    getattr(spool, "unreadable", _ignore)(entry.id, exc.__cause__)
                    continue
                for m in messages:
                    if not current():
                        return
                    if not link.send(conn, (m,)):
                        link.suspect_dead(conn, "replay publish refused by the MQTT client")
                        return
                    self._counters["replayed_messages"] += 1
                if delivered is not None and messages:
                    delivered.record_row(entry.id)
                paced += 1
                if paced % chunk == 0:  # yield to live ticks, holding the rate
                    await pacer.pace(paced)
            await pacer.pace(paced, force=True)
            if not current() or not await link.barrier(conn):
                return
            spool.ack(done)
            if delivered is not None:
                acked = set(done)
                for entry in entries:
                    if entry.id in acked:
                        recorded = delivered.overlaps(entry.device_id, entry.timestamps())
                        delivered.discard(entry.device_id, entry.samples if recorded else (), entry.id)
            self._counters["replayed_rows"] += len(done)
            sent_rows += len(done)
        left = spool.pending(fmt)
        if delivered is not None and not left:
            delivered.forget()
        if sent_rows:
            log.info("spool replayed format=%s rows=%d seconds=%.1f left=%d", fmt, sent_rows,
                     time.monotonic() - started, left)

    def _rate(self, spool: ReplaySpool, fmt: Format) -> float:
        """Rows per second: the policy's least rate, or replay_live_factor times the rate the rows were
        spooled at (what the fleet produced while the broker was away), whichever is higher."""
        policy = self._link.policy
        spooled = getattr(spool, "spooled_rate", None)
        live = spooled(fmt) if spooled is not None else None
        return max(policy.replay_rows_per_s, policy.replay_live_factor * live) if live else policy.replay_rows_per_s

    def _historical_messages(self, entry: Any) -> list[Outgoing]:
        """A row's messages: its parsed rows straight to DATA when the target can (Sparkplug) and the host
        has none of its values, else its samples (those the host has left out)."""
        delivered = self._delivered
        rows = getattr(entry, "rows", None)
        if rows is not None and self._from_rows is not None \
                and (delivered is None or not delivered.overlaps(entry.device_id, entry.timestamps())):
            try:
                return self._from_rows(entry, rows) if rows else []
            except (TypeError, ValueError):
                pass  # not as encode_samples writes it: read as samples (decode_samples' leniency), or dropped
        try:
            samples = entry.samples
        except (TypeError, ValueError) as exc:
            raise _Unreadable from exc
        if delivered is not None:
            samples = delivered.fresh(entry.device_id, samples)
        if not samples:
            return []
        if not all(map(_historical_of, samples)):  # the spool hands them out historical already
            samples = [s if s.historical else _as_historical(s) for s in samples]
        return self._target.historical(entry, samples)


class _Unreadable(Exception):
    """A spool row that is not one (its cause says why): dropped and counted by the spool."""


def _ignore(*args: object) -> None:
    return None


class _Pacer:
    """Holds a replay to its rate, counted from the replay's start (not per chunk): the query, the barrier
    and the delete of every step eat into the sleeps, not into the rate (paced per chunk, those took ~25 %
    of a step on top, and a 12x pace delivered 9x).

    Behind the pace, a yield costs a whole event-loop turn, which under the live load of a large fleet is
    far longer than a chunk's work (1,000 machines: ~0.5 s a turn, one chunk of 50 rows each, ~90 rows/s). So, behind
    the pace, the replay keeps the loop for up to SLICE_S of work before it yields."""

    def __init__(self, started: float, rate: float) -> None:
        self._started = started
        self._rate = rate
        self._slice_from = time.monotonic()

    async def pace(self, rows: int, force: bool = False) -> bool:
        """Called after `rows` were sent: sleep if ahead of the pace, yield if the slice is spent (or
        `force`); True if it gave the loop away."""
        now = time.monotonic()
        ahead = self._started + rows / self._rate - now
        if ahead <= 0 and not force and now - self._slice_from < SLICE_S:
            return False
        await asyncio.sleep(max(0.0, ahead))
        self._slice_from = time.monotonic()
        return True


def _as_historical(s: Sample) -> Sample:
    """The sample marked historical (built directly: dataclasses.replace costs three times as much)."""
    return Sample(s.name, s.value, s.type, s.timestamp_ms, s.quality, True)
