"""When to read a CNC's clock between poll ticks, so its offset is known to milliseconds at any poll period.

The CNC clock shows whole seconds; a reading bounds the CNC-vs-gateway offset θ to one second, and only
a reading taken close to the moment the CNC's second flips bounds it tightly (edge.collect.clock). A
tick's own clock reading lands wherever the poll schedule puts it: at a period dividing one second every
tick sees the same phase and the offset stays ±500 ms. So the poller adds clock-only reads (one small
request, no data) timed by the tracker:

- **Narrowing.** While the offset is less sure than GOAL_S, read the clock at the gateway moment where the
  middle of the offset interval says the CNC second flips. The CNC shows either the new second (θ is in
  the upper half) or the old one (the lower half): each read halves the interval, so about seven take a
  fresh machine from ±500 ms to ±5 ms. They stop when two reads in a row no longer narrow it (the round
  trip is the limit then) and start again when the interval has grown to twice what they left, or when the
  machine's usual round trip has fallen to half what it was when they stopped: at a big fleet's start-up
  the gateway is busy with births, round trips are long and narrowing stops at ±100-250 ms; without the
  second rule it would stay there for half an hour (drift widens the interval by 0.1 ms a second), and so
  would the stamps' error (issue 25). A restart that does not help stops again at the new round trip, so
  it costs two reads per halving of the round trip, not a steady rate. Nor is a narrowing read sent while
  the usual half round trip is not well below the uncertainty (NARROWED): it could not narrow, and the
  budget it would spend (the burst) is what the reads after the busy start need.
- **Ageing.** The tracker widens old readings by the assumed drift (MAX_DRIFT_RATE), so the interval
  grows slowly and one more narrowing read is due every minute or so.
- **Verifying.** Every VERIFY_EVERY_S one read just before (then, next time, just after) the predicted
  flip, by more than the current uncertainty: if the CNC clock was set by less than a second (a plant
  clock sync, an operator), that reading contradicts the interval and the tracker re-syncs; a step of a
  second or more is caught by any tick.

A budget caps it all: at most BURST reads in a row and PER_MINUTE per minute sustained (a token bucket),
so a thousand machines stay cheap whatever their clocks do. At steady state a machine takes about two
such reads a minute (docs/performance.md has the measured rate). No read is placed at the CNC's
midnight: the native clock read is date then time (two subpackets), which could straddle the day.
"""

from __future__ import annotations

import enum
import math
from datetime import datetime

from edge.collect.clock import ClockTracker

GOAL_S = 0.010  # narrow until the offset is known to ±10 ms (Clock/Synchronised needs ±20 ms)
VERIFY_EVERY_S = 60.0  # one read beside the predicted flip this often: sub-second clock steps
VERIFY_MARGIN_S = 0.002  # a verifying read sits this far beyond the uncertainty from the flip
BURST = 12  # reads the budget allows in a row (a fresh machine needs about seven)
PER_MINUTE = 4.0  # and sustained
LEAD_S = 0.002  # a read is planned at least this far ahead of now (the event loop's timer granularity)
NARROWED = 0.75  # a narrowing read that leaves more than this share of the uncertainty did not help
FRUITLESS_LIMIT = 2  # unhelpful narrowing reads in a row before narrowing rests
REOPEN_SHARE = 0.5  # narrowing resumes when the usual round trip falls to this share of the one it rested at
REPLAN_S = 1.0  # a plan is recomputed at least this often (the uncertainty grows as readings age)
MIDNIGHT_GUARD_S = 2  # seconds either side of the CNC's midnight with no read


class ProbeKind(enum.Enum):
    NARROW = "narrow"
    VERIFY = "verify"


class ClockProbes:
    """Plans the clock-only reads of one machine: `send_at(now)`, then `done(now)` after each read."""

    def __init__(self, tracker: ClockTracker, goal_s: float = GOAL_S, verify_every_s: float = VERIFY_EVERY_S,
                 burst: int = BURST, per_minute: float = PER_MINUTE) -> None:
        self.tracker = tracker
        self.goal_s = goal_s
        self.verify_every_s = verify_every_s
        self.burst = burst
        self.per_second = per_minute / 60.0
        self.sent = 0  # reads done (the budget's own count; the poller also counts them in its stats)
        self._tokens = float(burst)
        self._tokens_at: float | None = None
        self._fruitless = 0
        self._usual = math.inf  # half the machine's usual round trip, as the poller last said
        self._rested_usual = math.inf  # and as it was when narrowing rested
        self._settled = math.inf  # the uncertainty the last read left
        self._verified: float | None = None  # when the last verifying read was done (None: none yet)
        self._side = -1.0  # the side of the flip the next verifying read takes (-1: before it)
        self._kind = ProbeKind.NARROW
        self._before: float | None = None  # the uncertainty when the planned read was planned
        self._send = math.inf
        self._valid_until = -math.inf
        self._revision = -1

    # ---- planning ------------------------------------------------------------------------------------
    def send_at(self, now: float, half_rtt_s: float = 0.0, usual_half_rtt_s: float | None = None) -> float:
        """Monotonic time to send the next clock-only read (math.inf: none wanted), so that the middle of
        its round trip falls on the moment planned. Cheap when nothing changed: the poller asks every tick.

        `usual_half_rtt_s` (half the machine's usual round trip, edge.collect.answer_time; the last one when
        not given) says when narrowing that rested on a long round trip may help again."""
        usual = half_rtt_s if usual_half_rtt_s is None else usual_half_rtt_s
        self._usual = usual  # the plan is remade at least every REPLAN_S, which sees it
        revision = self.tracker.revision
        if revision == self._revision and now < self._valid_until:
            return self._send
        self._revision = revision
        self._send = self._plan(now, max(half_rtt_s, 0.0))
        self._valid_until = min(self._send, now + REPLAN_S)
        return self._send

    @property
    def kind(self) -> ProbeKind:
        """What the planned read is for."""
        return self._kind

    def _plan(self, now: float, half_rtt: float) -> float:
        tracker = self.tracker
        offset = tracker.offset_s
        uncertainty = tracker.uncertainty_at(now)
        if offset is None or uncertainty is None or tracker.use_gateway_time:
            return math.inf  # no CNC time in use: nothing to refine
        if uncertainty > 2 * self._settled:
            self._fruitless = 0  # the interval grew (readings aged out, a re-sync): narrowing helps again
        elif (self._fruitless >= FRUITLESS_LIMIT and uncertainty > self.goal_s
              and self._usual <= REOPEN_SHARE * self._rested_usual):
            self._fruitless = 0  # round trips are quicker than the ones narrowing rested on: try again
        self._before = uncertainty
        if uncertainty > self.goal_s and self._fruitless < FRUITLESS_LIMIT and self._usual < uncertainty * NARROWED:
            self._kind, earliest, aim = ProbeKind.NARROW, now, 0.0
        else:
            verified = now if self._verified is None else self._verified
            self._verified = verified
            self._kind, earliest = ProbeKind.VERIFY, verified + self.verify_every_s
            aim = self._side * (uncertainty + half_rtt + VERIFY_MARGIN_S)
        earliest = max(earliest, now + LEAD_S + half_rtt, self._budget_ready())
        return self._flip_after(earliest, offset, aim) - half_rtt

    def _flip_after(self, earliest: float, offset: float, aim: float) -> float:
        """The first gateway moment at or after `earliest` that is `aim` seconds from a predicted CNC second
        flip (the CNC shows second N from `N - offset` on), skipping the CNC's midnight."""
        second = math.ceil(earliest + offset - aim)
        zone = self.tracker.zone
        for _ in range(2 * MIDNIGHT_GUARD_S + 2):
            local = datetime.fromtimestamp(second, zone)
            since_midnight = local.hour * 3600 + local.minute * 60 + local.second
            if MIDNIGHT_GUARD_S <= since_midnight <= 86400 - MIDNIGHT_GUARD_S:
                break
            second += 1
        return second - offset + aim

    # ---- budget --------------------------------------------------------------------------------------
    def _refill(self, now: float) -> None:
        if self._tokens_at is not None:
            self._tokens = min(float(self.burst), self._tokens + (now - self._tokens_at) * self.per_second)
        self._tokens_at = now

    def _budget_ready(self) -> float:
        """When the budget allows the next read (-inf: now)."""
        if self._tokens >= 1.0 or self._tokens_at is None:
            return -math.inf
        return self._tokens_at + (1.0 - self._tokens) / self.per_second

    # ---- after a read --------------------------------------------------------------------------------
    def done(self, now: float) -> None:
        """A planned read was done (and its reading, if any, observed by the tracker): book it."""
        self._refill(now)
        self._tokens -= 1.0
        self.sent += 1
        after = self.tracker.uncertainty_at(now)
        if self._kind is ProbeKind.VERIFY:
            self._verified = now
            self._side = -self._side
        elif after is not None and self._before is not None and after <= self._before * NARROWED:
            self._fruitless = 0
        else:
            self._fruitless += 1
            if self._fruitless == FRUITLESS_LIMIT:
                self._rested_usual = self._usual  # narrowing rests: resume when round trips halve
        if self._verified is None:
            self._verified = now  # verifying starts VERIFY_EVERY_S after the first read
        self._settled = after if after is not None else math.inf
        self._revision = -1  # plan afresh
