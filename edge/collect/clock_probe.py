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
so a thousand machines stay cheap whatever their clocks do. And a calendar shared by the gateway's machines
(ProbeCalendar) caps how many narrowing reads aim at one few-millisecond bin: CNC clocks synchronised by NTP
all flip at the same instant, so without it a fleet's narrowing reads arrive together and each one's round
trip (the width its reading leaves) is the crowd's, not the machine's (docs/performance.md, the clock at
1,000 x 1 Hz). A narrowing read need not aim at the exact middle: anywhere within a quarter of the
uncertainty from it still halves the interval nearly as well, so the crowd spreads over that window (wide
at start-up, when every machine narrows) or, when it is full, waits for the same phase a second later. At
steady state a machine takes about two such reads a minute (docs/performance.md has the measured rate).
No read is placed at the CNC's midnight: the native clock read is date then time (two subpackets), which
could straddle the day.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Iterator
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
BIN_S = 0.005  # the calendar's bins: narrowing reads aiming within one such slice of gateway time
PER_BIN = 8  # narrowing reads a bin takes (a read costs the loop ~0.1 ms: 8 keep a bin's queue under 1 ms)
AIM_SHARE = 0.25  # a narrowing read aims within this share of the uncertainty from the interval's middle
LOOK_AHEAD_S = 8  # seconds searched for a bin with room; beyond, the least booked one is taken


class ProbeCalendar:
    """Narrowing reads booked by the gateway moment they aim at, in BIN_S bins of PER_BIN reads; one per
    gateway (edge.collect.clock_feed.FLEET_CALENDAR). Each ClockProbes holds at most one booking for a read
    not yet done, given back when it is replanned; a read done keeps its place, and bins in the past are
    forgotten."""

    def __init__(self, per_bin: int = PER_BIN, bin_s: float = BIN_S) -> None:
        self.per_bin = per_bin
        self.bin_s = bin_s
        self._booked: dict[int, int] = {}
        self._purged_at = -math.inf

    def booked(self, moment: float) -> int:
        return self._booked.get(math.floor(moment / self.bin_s), 0)

    def book(self, moment: float) -> int:
        key = math.floor(moment / self.bin_s)
        self._booked[key] = self._booked.get(key, 0) + 1
        if moment - self._purged_at > 1.0:
            self._purge(moment)
        return key

    def release(self, key: int) -> None:
        left = self._booked.get(key, 0) - 1
        if left > 0:
            self._booked[key] = left
        else:
            self._booked.pop(key, None)

    def _purge(self, moment: float) -> None:
        """Bookings more than a few seconds old (a machine removed before its read) are dropped."""
        self._purged_at = moment
        oldest = math.floor((moment - 2 * LOOK_AHEAD_S) / self.bin_s)
        for key in [k for k in self._booked if k < oldest]:
            del self._booked[key]

    def slot(self, flips: Iterable[float], spread: float) -> float:
        """The gateway moment to aim at: within `spread` of one of `flips` (predicted flips, earliest first),
        nearest the earliest flip with room; the least booked moment when none has."""
        bin_s = self.bin_s
        steps = int(spread / bin_s)
        offsets = [0.0]
        for step in range(1, steps + 1):
            offsets += (step * bin_s, -step * bin_s)
        least, least_count = math.nan, math.inf
        for flip in flips:
            for offset in offsets:
                count = self.booked(flip + offset)
                if count < self.per_bin:
                    return flip + offset
                if count < least_count:
                    least, least_count = flip + offset, count
        return least


class ProbeKind(enum.Enum):
    NARROW = "narrow"
    VERIFY = "verify"


class ClockProbes:
    """Plans the clock-only reads of one machine: `send_at(now)`, then `done(now)` after each read."""

    def __init__(self, tracker: ClockTracker, goal_s: float = GOAL_S, verify_every_s: float = VERIFY_EVERY_S,
                 burst: int = BURST, per_minute: float = PER_MINUTE, calendar: ProbeCalendar | None = None) -> None:
        self.tracker = tracker
        self.calendar = calendar  # None: narrowing reads aim at the middle, uncapped (a lone machine)
        self._booking: int | None = None  # the calendar bin this machine's planned read holds
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
        self._clear: tuple[float, int] = (math.nan, 0)  # _clear_of_midnight's last (second asked, answer)

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
        if self._booking is not None:
            self._unbook()
        send = self._send = self._plan(now, 0.0 if half_rtt_s < 0.0 else half_rtt_s)  # max(half_rtt_s, 0.0)
        until = now + REPLAN_S
        self._valid_until = send if send < until else until  # min(send, until), as the min() it replaces
        return send

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
        if self._kind is ProbeKind.NARROW and self.calendar is not None:
            return self._booked_narrowing(earliest, offset, uncertainty) - half_rtt
        return self._flip_after(earliest, offset, aim) - half_rtt

    def _booked_narrowing(self, earliest: float, offset: float, uncertainty: float) -> float:
        """A narrowing read's aim, booked in the gateway's calendar (see ProbeCalendar)."""
        assert self.calendar is not None
        spread = AIM_SHARE * uncertainty
        moment = self.calendar.slot(self._flips(earliest + spread, offset), spread)
        self._booking = self.calendar.book(moment)
        return moment

    def _flips(self, earliest: float, offset: float) -> Iterator[float]:
        """The predicted CNC second flips from `earliest` on, LOOK_AHEAD_S of them (computed as asked)."""
        flip = self._flip_after(earliest, offset, 0.0)
        for _ in range(LOOK_AHEAD_S):
            yield flip
            flip = self._flip_after(flip + 0.5, offset, 0.0)

    def _unbook(self) -> None:
        if self._booking is not None and self.calendar is not None:
            self.calendar.release(self._booking)
        self._booking = None

    def _flip_after(self, earliest: float, offset: float, aim: float) -> float:
        """The first gateway moment at or after `earliest` that is `aim` seconds from a predicted CNC second
        flip (the CNC shows second N from `N - offset` on), skipping the CNC's midnight."""
        second = math.ceil(earliest + offset - aim)
        return self._clear_of_midnight(second) - offset + aim

    def _clear_of_midnight(self, second: int) -> int:
        """The first CNC second from `second` on that is not within MIDNIGHT_GUARD_S of its midnight. The last
        answer is kept: a plan is remade at every new CNC second (every tick at 1 Hz) and mostly aims at the
        same second again (a verifying read's, a minute ahead), and the zone's local time costs ~0.7 us."""
        asked, answer = self._clear
        if second == asked:
            return answer
        zone = self.tracker.zone
        found = second
        for _ in range(2 * MIDNIGHT_GUARD_S + 2):
            local = datetime.fromtimestamp(found, zone)
            since_midnight = local.hour * 3600 + local.minute * 60 + local.second
            if MIDNIGHT_GUARD_S <= since_midnight <= 86400 - MIDNIGHT_GUARD_S:
                break
            found += 1
        self._clear = (second, found)
        return found

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
        self._booking = None  # the read took its place in that bin: it stays booked until the bin is past
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
