"""Is another gateway using our Sparkplug identity on this broker? Evidence in, one verdict out (sans-IO).

Two gateways with the same group/edge node id (a cloned config) fight without a word: with the client id
derived from the ids, the broker closes one session each time the other connects and both reconnect in
under a second (a birth per connect: 105 NBIRTH in 40 s seen); with distinct client ids both stay up and
hosts see two interleaved seq streams and ask for rebirths. The sessions feed what they see here:
- another session's NBIRTH for our id (a payload we did not send, or a second copy of one we did), or an
  NDEATH with a bdSeq we never used;
- the broker taking our session: MQTT 5 reason "Session taken over", or (3.1.1, no reason) several sessions
  in a row closed by the broker soon after their CONNACK, each time taking us straight back (edge.publish.mqtt
  reports a loss only then: a broker restart refuses the first reconnect) and not for a missed keepalive.
The first evidence is one ERROR naming the id and what was seen; while a conflict lasts (evidence within
`hold_s`) reconnects and rebirths wait at least `backoff_s` (one a minute), and every piece of evidence is
counted (focas_edge_identity_conflicts_total). Without evidence for `hold_s` the conflict is over (INFO).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from edge.publish import payload as pl

log = logging.getLogger(__name__)

BACKOFF_S = 60.0  # while in conflict: at most one reconnect and one rebirth per this many seconds
SHORT_LOSSES = 3  # sessions in a row the broker closed within hold_s of their CONNACK (3.1.1: no reason)
TAKEN_OVER = "session taken over"  # MQTT 5 DISCONNECT reason 0x8E, as paho spells it (lower-cased)
KEEPALIVE = "keep alive timeout"  # paho's reason when no PINGRESP came: the network, not another client


def bdseq_of(data: bytes) -> int | None:
    """The bdSeq an NBIRTH or NDEATH carries; None when the payload has none (or is not Sparkplug)."""
    try:
        decoded = pl.decode(data)
    except ValueError:  # another client's junk on our topic: no number, still evidence
        return None
    return next((int(m.long_value) for m in decoded.metrics if m.name == pl.BDSEQ_METRIC), None)


@dataclass(frozen=True, slots=True)
class Conflict:
    """What the status page shows: the id, what was seen last, since when (epoch s) and how often."""

    identity: str
    seen: str
    since: float
    count: int


class IdentityGuard:
    """One per gateway, shared by its MQTT connections; call it on the event loop."""

    def __init__(self, identity: str, *, backoff_s: float = BACKOFF_S,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time) -> None:
        self.identity = identity  # "<group_id>/<edge_node_id>"
        self.backoff_s = backoff_s
        self.hold_s = 3 * backoff_s  # two gateways backing off take turns: evidence every ~2 x backoff
        self._clock = clock
        self._wall = wall
        self.count = 0  # pieces of evidence seen (the metric)
        self._last_evidence: float | None = None
        self._current: Conflict | None = None
        self._short_losses: dict[str, int] = {}  # per client id (Sparkplug and JSON connections)
        # NBIRTH payloads we sent whose echo has not come back yet: each echoes once (QoS 0, one subscription),
        # so a second copy is another session's birth, byte-equal when a clone births in the same millisecond.
        self._unechoed_births: deque[bytes] = deque(maxlen=8)
        self._own_bdseqs: deque[int] = deque(maxlen=16)  # bdSeqs our CONNECTs carried

    # -- the verdict -----------------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        """A conflict was seen within hold_s; logs the end of it once it is over."""
        if self._last_evidence is None:
            return False
        if self._clock() - self._last_evidence <= self.hold_s:
            return True
        log.info("identity conflict over: no other session for %s seen for %.0f s", self.identity, self.hold_s)
        self._last_evidence = None
        self._current = None
        return False

    @property
    def conflict(self) -> Conflict | None:
        return self._current if self.active else None

    def reconnect_floor_s(self) -> float:
        """The least reconnect delay now: backoff_s while in conflict, else 0."""
        return self.backoff_s if self.active else 0.0

    def rebirth_interval_s(self, configured: float) -> float:
        return max(configured, self.backoff_s) if self.active else configured

    # -- what the sessions report ----------------------------------------------------------------------

    def sent_birth(self, payload: bytes) -> None:
        self._unechoed_births.append(payload)

    def used_bdseq(self, bdseq: int) -> None:
        self._own_bdseqs.append(bdseq)

    def nbirth_seen(self, payload: bytes, bdseq: int | None, ours: int | None) -> None:
        """An NBIRTH on our own topic: ours echoed back, or another session's."""
        if payload in self._unechoed_births:
            self._unechoed_births.remove(payload)  # our echo, once
            return
        self._evidence(f"an NBIRTH for this id from another session (its bdSeq {bdseq}, ours {ours})")

    def ndeath_seen(self, bdseq: int | None, ours: int | None) -> None:
        """An NDEATH on our own topic: one of our earlier sessions' Will, or another session's."""
        if bdseq is not None and bdseq in self._own_bdseqs:
            return
        self._evidence(f"an NDEATH for this id with bdSeq {bdseq} that this gateway never used (ours {ours})")

    def session_lost(self, client_id: str, lasted_s: float, reason: str) -> None:
        """The broker ended a session we did not end (a drop we asked for is not reported).

        Two gateways on one client id take turns: the one that found the conflict first reconnects once a
        minute, so the other sees sessions of a minute end; hence "short" is anything under hold_s.
        """
        if TAKEN_OVER in reason.lower():
            self._evidence(f"the broker handed client id {client_id} to another connection ({reason})")
            return
        if lasted_s >= self.hold_s or KEEPALIVE in reason.lower():
            self._short_losses.pop(client_id, None)
            return
        if self.active:
            self._evidence(f"the broker closed the session of client id {client_id} {lasted_s:.1f} s after "
                           f"it connected ({reason})")
            return
        strikes = self._short_losses.get(client_id, 0) + 1
        self._short_losses[client_id] = strikes
        if strikes >= SHORT_LOSSES:
            self._short_losses.pop(client_id, None)
            self._evidence(f"the broker closed the session of client id {client_id} {strikes} times in a row, "
                           f"each within {self.hold_s:.0f} s of connecting (last after {lasted_s:.1f} s: "
                           f"{reason}); another client probably connects with the same client id")

    def _evidence(self, seen: str) -> None:
        new = not self.active
        self.count += 1
        self._last_evidence = self._clock()
        since = self._wall() if new or self._current is None else self._current.since
        self._current = Conflict(self.identity, seen, since, self.count)
        if new:
            log.error("identity conflict: another gateway uses %s on this broker; seen: %s. Backing "
                      "off: at most one reconnect and one rebirth every %.0f s while it lasts. Fix: give each "
                      "gateway its own mqtt.sparkplug.edge_node_id (and mqtt.client_id)",
                      self.identity, seen, self.backoff_s)
        else:
            log.debug("identity conflict goes on id=%s seen=%s count=%d", self.identity, seen, self.count)
