"""CNC clock tracking: source timestamps from the CNC's own clock, finer than its one-second resolution.

Every poll batch also reads the CNC clock (local wall time, whole seconds). For each reading we know
the gateway's monotonic time at the midpoint of the request, `m`, and the CNC's truncated time
converted to UTC with the machine's time zone, `c`. If the CNC clock runs at `m + θ` (θ the unknown
CNC-vs-gateway offset), truncation means

        c  <=  m + θ  <  c + 1        so        θ ∈ [c - m, c - m + 1)

(each bound widened by half the request's round trip, since the CNC read its clock somewhere inside
the request, not exactly at its midpoint).

Each tick narrows the interval: θ ≥ max(c_i - m_i) and θ < min(c_i - m_i + 1) over a window of recent
ticks. Ticks land at different phases of the CNC second (polling is jittered and not a divisor of
1 s), so the ticks just before and just after each "second flip" pin θ down to roughly the tick
spacing plus the request's round-trip uncertainty; the estimate is the middle of the interval. If the
interval becomes empty (the CNC clock was set, a DST or time-zone jump, or drift over a long window),
the window restarts from the newest reading. Using the gateway's monotonic clock keeps the estimate
immune to NTP steps on the gateway itself.

A reading that contradicts the window by more than STEP_MIN_S is a *step*: the CNC clock was set (by an
operator, a DST rule, a clock sync at the control). It is counted (`steps`, `last_step_s`, which the poller
logs once) and the window restarts from that reading (as for any contradiction), so the offset is
re-synced at once. Stamps, though, never jump back: when the offset falls (a step back, or a bound moving
as the interval narrows), the offset the stamps use falls at most SLEW_RATE seconds per second, so stamps
keep advancing (at half speed) until they meet the CNC's new time; a step forward is followed at once. A
historian therefore never gets a value stamped before one it already has, and a 30 s step back is
absorbed in about 60 s.

The CNC time of any gateway moment is then `m_now + θ`. The skew — CNC minus gateway wall time — is
published as a metric. Beyond `max_skew_s` (dead clock battery, wrong time zone) the tracker says to
use gateway time instead, with the reason, and goes back to CNC time as soon as the skew is within
the limit again.

Ticks alone do not always narrow the interval: at a poll period that divides one second (1 s, 500 ms,
250 ms, even 50 ms) every tick reads the CNC clock at the same few phases of its second, so θ stays
known only to the tick spacing (±500 ms at 1 Hz). The poller therefore adds a few clock-only reads
timed where the tracker predicts the CNC second flips (edge.collect.clock_probe): each one halves the
interval, so a handful reach the round-trip limit. `synchronised` says when stamps are within
SYNC_TARGET_S of the CNC's clock; until then stamps are the middle of the interval, off by at most
`uncertainty_s`.

Clocks drift apart (a CNC's real-time clock and the gateway's crystal, tens of ppm each), so a reading
is trusted less as it ages: with `drift_rate` r a reading taken at `m_i` bounds θ at a later time `t`
only to [lower_i - r(t - m_i), upper_i + r(t - m_i)]. The estimate (the middle) does not move as
readings age, the uncertainty grows by r per second, so `uncertainty_s` stays an honest bound and the
poller re-reads the clock when it has grown past its goal. Stored as `lower_i + r m_i` and
`upper_i - r m_i`, a reading's rank among the others never changes with time, so the sliding-window
extremes below still hold.
"""

from __future__ import annotations

import enum
from datetime import datetime, timedelta
from typing import Final
from zoneinfo import ZoneInfo

DEFAULT_WINDOW_S = 300.0
MAX_READINGS = 512
STEP_MIN_S = 1.0  # a reading this far outside the window's interval is a clock step, not drift or jitter
SLEW_RATE = 0.5  # seconds the stamping offset may fall per second: stamps advance at least at half speed
SYNC_TARGET_S = 0.020  # stamps within this of the CNC's clock count as synchronised (Clock/Synchronised)
MAX_DRIFT_RATE = 100e-6  # CNC vs gateway clock rate difference assumed at most (s/s): two crystals, some heat


_EPOCH = datetime(1970, 1, 1)
_SECOND = timedelta(seconds=1)


def cnc_to_utc_seconds(cnc_wall: datetime, zone: ZoneInfo) -> float:
    """A naive CNC wall-clock time in `zone` as epoch seconds (UTC); aware values are taken as they are.

    The naive case is `cnc_wall.replace(tzinfo=zone).timestamp()` (the zone's offset for that wall time and
    its fold, integer microseconds divided once), without the replace: 0.3 instead of 1.7 us, once a CNC
    second per machine."""
    if cnc_wall.tzinfo is not None:
        return cnc_wall.timestamp()
    offset = zone.utcoffset(cnc_wall)
    assert offset is not None  # a ZoneInfo always has one
    return (cnc_wall - _EPOCH - offset) / _SECOND


class ClockTransition(enum.Enum):
    """What changed with the latest reading, for a single log line."""

    TO_GATEWAY = "to_gateway"
    TO_CNC = "to_cnc"


# A reading as kept in the window: a plain tuple, made in 0.05 us where a slotted dataclass took 0.23 (one a CNC
# second, every tick at 1 Hz). Its fields, by index:
_LOWER: Final = 0  # c - m - u (+ r m, see the module docstring): the offset is at least this
_UPPER: Final = 1  # c - m + 1 + u (- r m): and less than this
_MONOTONIC: Final = 2
_SEQ: Final = 3  # its position in the stream of readings
_Reading = tuple[float, float, float, int]


class ClockTracker:
    """Offset estimate between one CNC's clock and the gateway's; see the module docstring."""

    def __init__(self, zone: ZoneInfo | str, max_skew_s: float, window_s: float = DEFAULT_WINDOW_S,
                 drift_rate: float = 0.0) -> None:
        self.zone = zone if isinstance(zone, ZoneInfo) else ZoneInfo(zone)
        self.max_skew_s = max_skew_s
        self.window_s = window_s
        self.drift_rate = drift_rate  # r: how fast an old reading's bounds widen (0: they never do)
        # Only the readings that can still be an extreme of the window are kept (a reading whose bound a
        # later one beats never matters again): sliding-window extremes in amortised O(1) per tick, and a
        # few readings per machine instead of the whole window (512 readings were ~60 KB per machine).
        # Readings whose `lower` decreases (front = max) and whose `upper` increases (front = min).
        self._count = 0  # readings observed since the last reset
        # Lists, not deques: they hold a few readings, and an empty deque is 0.8 kB (1.5 MB at 1,000 machines).
        self._max_lower: list[_Reading] = []
        self._min_upper: list[_Reading] = []
        self._low = float("-inf")  # the interval's bounds as stored (aged by r at the time asked)
        self._high = float("inf")
        self._latest = 0.0  # monotonic time of the newest reading
        self.revision = 0  # bumped by every reading and reset: a cache key for plans made from the interval
        # Plain attributes, not properties: read at every new CNC second (a property call is ~0.05 us each).
        self.skew_s: float | None = None  # CNC minus gateway wall time at the last reading (positive: CNC ahead)
        self.use_gateway_time = True
        self.reason: str | None = "no CNC clock reading yet"  # why gateway time is used (None: CNC time is)
        self.restarts = 0
        self.steps = 0  # CNC clock steps seen (see the module docstring)
        self.last_step_s: float | None = None  # the latest step's size, seconds (negative: set back)
        self._stamp: tuple[float, float] | None = None  # (monotonic, offset) of the last CNC-time stamp

    # ---- input -------------------------------------------------------------------------------------
    def observe(self, cnc_wall: datetime, gateway_monotonic: float, gateway_wall: float,
                half_rtt_s: float = 0.0) -> ClockTransition | None:
        """Add one CNC clock reading taken at the request midpoint (gateway monotonic and wall seconds).

        `half_rtt_s` (half the request's round trip) widens the reading's interval: the CNC sampled its
        clock somewhere inside the request, not necessarily at its midpoint.
        """
        return self.observe_epoch(cnc_to_utc_seconds(cnc_wall, self.zone), gateway_monotonic, gateway_wall,
                                  half_rtt_s)

    def narrows(self, cnc_epoch_s: float, gateway_monotonic: float, half_rtt_s: float = 0.0) -> bool:
        """Whether this reading (the CNC time as epoch seconds) would tighten the current interval.

        A poller reads the same CNC second about ten times: only a reading that moves a bound needs
        observing (the first of a second raises the lower bound, a later one may lower the upper).
        """
        base = cnc_epoch_s - gateway_monotonic
        margin = max(half_rtt_s, 0.0)
        aged = self.drift_rate * gateway_monotonic
        return base - margin + aged > self._low or base + 1.0 + margin - aged < self._high

    def observe_epoch(self, cnc_epoch_s: float, gateway_monotonic: float, gateway_wall: float,
                      half_rtt_s: float = 0.0) -> ClockTransition | None:
        """As observe(), with the CNC time already converted to epoch seconds (UTC).

        Runs at every new CNC second, which is every tick at 1 Hz: the window's extremes are updated here
        rather than through helpers, and the rare paths (a step, a restart, gateway time) are calls."""
        base = cnc_epoch_s - gateway_monotonic
        margin = 0.0 if half_rtt_s < 0.0 else half_rtt_s  # max(half_rtt_s, 0.0) without the call
        aged = self.drift_rate * gateway_monotonic  # 0.0 without drift: the bounds exactly as read
        lower = base - margin + aged
        upper = base + 1.0 + margin - aged
        spread = 2 * aged  # a stored lower minus a stored upper, less this, is the aged gap at this moment
        count = self._count
        if count:
            above, below = lower - self._high, self._low - upper
            if (below if below > above else above) - spread > STEP_MIN_S:  # max(above, below)
                self._stepped(base + 0.5)
        count += 1
        self._count = count
        self.revision += 1
        self._latest = gateway_monotonic
        reading = (lower, upper, gateway_monotonic, count)
        max_lower, min_upper = self._max_lower, self._min_upper
        while max_lower and max_lower[-1][_LOWER] <= lower:
            max_lower.pop()
        max_lower.append(reading)
        while min_upper and min_upper[-1][_UPPER] >= upper:
            min_upper.pop()
        min_upper.append(reading)
        self._evict(count - MAX_READINGS, gateway_monotonic, self.window_s)
        low, high = max_lower[0][_LOWER], min_upper[0][_UPPER]
        if low - high >= spread:
            # Inconsistent with the window: the CNC clock jumped (or drifted). Keep the newest
            # readings that still agree with each other and drop the older ones.
            self.restarts += 1
            self._evict(self._agreeing_since(spread), gateway_monotonic, float("inf"))
            low, high = max_lower[0][_LOWER], min_upper[0][_UPPER]
        self._low, self._high = low, high
        skew = gateway_monotonic + (low + high) / 2 - gateway_wall  # the offset_s of the new interval
        self.skew_s = skew
        if abs(skew) > self.max_skew_s:
            return self._beyond_skew(skew)
        self.reason = None
        if self.use_gateway_time:
            self.use_gateway_time = False
            return ClockTransition.TO_CNC
        return None

    def _stepped(self, new_offset: float) -> None:
        """The CNC clock was set: count it. The reading contradicts the window, so the restart below keeps
        only the readings of the new clock: the offset is re-synced with this very reading."""
        old = self.offset_s
        self.steps += 1
        self.last_step_s = new_offset - old if old is not None else None

    def _beyond_skew(self, skew: float) -> ClockTransition | None:
        """The CNC clock is off by more than max_skew_s: gateway time, with the reason."""
        direction = "ahead of" if skew > 0 else "behind"
        self.reason = f"CNC clock {abs(skew):.1f}s {direction} the gateway, beyond max_skew_s {self.max_skew_s:g}"
        if self.use_gateway_time:
            return None
        self.use_gateway_time = True
        return ClockTransition.TO_GATEWAY

    def _evict(self, first_seq: int, now: float, window_s: float) -> None:
        """Leave the window: readings before `first_seq` or older than `window_s` at `now` (both rise
        from front to back of each list, so only fronts go). The newest reading always stays."""
        for extremes in (self._max_lower, self._min_upper):
            while len(extremes) > 1 and (extremes[0][_SEQ] < first_seq or now - extremes[0][_MONOTONIC] > window_s):
                del extremes[0]

    def _agreeing_since(self, spread: float) -> int:
        """The first reading of the longest run of newest readings whose intervals (aged to the newest
        reading: `spread`, see observe_epoch) still intersect.

        Walking back from the newest reading, the intersection only changes at a kept reading (any other
        is beaten by a later one in both bounds), so the kept ones, merged newest first, decide it.
        """
        events = sorted((*self._max_lower, *self._min_upper), key=lambda r: r[_SEQ], reverse=True)
        low, high = float("-inf"), float("inf")
        for reading in events:
            low, high = max(low, reading[_LOWER]), min(high, reading[_UPPER])
            if low - high >= spread:
                return reading[_SEQ] + 1
        return events[-1][_SEQ]

    # ---- output ------------------------------------------------------------------------------------
    @property
    def offset_s(self) -> float | None:
        """CNC UTC time minus gateway monotonic time (middle of the feasible interval)."""
        if not self._count:
            return None
        return (self._low + self._high) / 2

    @property
    def uncertainty_s(self) -> float | None:
        """Half-width of the feasible interval at the newest reading: how far the estimate can be off."""
        return self.uncertainty_at(self._latest)

    def uncertainty_at(self, gateway_monotonic: float) -> float | None:
        """Half-width of the feasible interval at a gateway moment (it grows by `drift_rate` per second)."""
        if not self._count:
            return None
        return (self._high - self._low) / 2 + self.drift_rate * gateway_monotonic

    def slew_lag_at(self, gateway_monotonic: float) -> float:
        """How far above the estimate a stamp given at this moment would be (> 0 only while stamps slew
        after the offset fell: they may not go back)."""
        return self.stamp_quality_at(gateway_monotonic)[1]

    def synchronised_at(self, gateway_monotonic: float) -> bool:
        """Whether a stamp given at this moment is within SYNC_TARGET_S of the CNC's clock: CNC time in
        use, the offset known that well, and no slew after a step back still under way."""
        return self.stamp_quality_at(gateway_monotonic)[2]

    def stamp_quality_at(self, gateway_monotonic: float) -> tuple[float | None, float, bool]:
        """uncertainty_at, slew_lag_at and synchronised_at of one moment in one call: the Clock/* metrics
        ask for all three at every new CNC second (every tick at 1 Hz), where they were six calls."""
        if not self._count:
            return None, 0.0, False
        low, high = self._low, self._high
        uncertainty = (high - low) / 2 + self.drift_rate * gateway_monotonic  # uncertainty_at
        stamp = self._stamp
        if stamp is None:
            lag = 0.0
        else:
            last_mono, last_offset = stamp
            lag = max(last_offset - SLEW_RATE * max(gateway_monotonic - last_mono, 0.0) - (low + high) / 2, 0.0)
        return uncertainty, lag, not self.use_gateway_time and uncertainty + lag <= SYNC_TARGET_S

    def source_time_ms(self, gateway_monotonic: float, gateway_wall: float) -> int:
        """The timestamp for a sample taken now: CNC time in UTC ms, or gateway time when told to."""
        offset = self.offset_s
        if self.use_gateway_time or offset is None:
            self._stamp = None
            return round(gateway_wall * 1000)
        last = self._stamp
        if last is not None and offset < last[1]:  # falling: slew, never stamp before the last stamp
            floor = last[1] - SLEW_RATE * max(gateway_monotonic - last[0], 0.0)
            offset = max(offset, floor)
        self._stamp = (gateway_monotonic, offset)
        return round((gateway_monotonic + offset) * 1000)

    def reset(self) -> None:
        """Forget every reading (a different CNC behind the same address, or a clock set on purpose)."""
        self._count = 0
        self._max_lower.clear()
        self._min_upper.clear()
        self._low, self._high = float("-inf"), float("inf")
        self.revision += 1
        self.skew_s = None
        self._stamp = None
        self.use_gateway_time = True
        self.reason = "no CNC clock reading yet"
