"""What the plant page draws, recorded from the samples every output gets: state bands, sparklines, alarms.

A DeviceSink behind the publisher (edge.service.outputs): it sees the same births, data, events and
offlines, and keeps per machine
- the current band state (running, idle, feed hold, alarm, emergency, offline, unknown), derived from
  `Status/Execution` (MTConnect vocabulary) when the collector publishes it, else from the raw
  `Status/Run`; `Status/Emergency`, `Status/Alarm` and `Status/Availability` override it;
- the last hour as exact transitions, and the last 24 h as one dominant state per minute (a bytearray:
  1,000 machines cost 1.4 MB, however often they flap);
- spindle load and feed rate for the last hour, one peak per 30 s;
- the latest alarm raise/clear events (capped), and the `Utilisation/<STATE>` seconds when published.

Times are the gateway's clock at receipt, not the CNC timestamps: bands of different machines must line
up and never run backwards when a CNC clock is set. Values arrive by exception (only on change), so a
state lasts until the next sample says otherwise; an offline machine is OFFLINE, time before this
process saw a machine is UNKNOWN.
"""

from __future__ import annotations

import enum
import json
import math
import time
from array import array
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from edge.samples import MetricSpec, Sample


class Band(enum.IntEnum):
    """A state as the page colours it. The value is the byte stored per minute; the order is not trouble."""

    UNKNOWN = 0
    RUNNING = 1
    IDLE = 2
    FEED_HOLD = 3
    ALARM = 4
    EMERGENCY = 5
    OFFLINE = 6

    @property
    def css(self) -> str:
        return self.name.lower().replace("_", "-")

    @property
    def label(self) -> str:
        return BAND_LABELS[self]


BAND_LABELS = {Band.UNKNOWN: "unknown", Band.RUNNING: "running", Band.IDLE: "idle / ready",
               Band.FEED_HOLD: "feed hold", Band.ALARM: "alarm", Band.EMERGENCY: "emergency",
               Band.OFFLINE: "offline"}
# Most trouble first: the fleet overview sorts by it.
TROUBLE = (Band.EMERGENCY, Band.ALARM, Band.OFFLINE, Band.FEED_HOLD, Band.UNKNOWN, Band.IDLE, Band.RUNNING)
TROUBLE_RANK = {band: rank for rank, band in enumerate(TROUBLE)}

EXECUTION = "Status/Execution"
AVAILABILITY = "Status/Availability"
RUN = "Status/Run"
ALARM = "Status/Alarm"
EMERGENCY = "Status/Emergency"
ALARM_EVENT = "Alarm/Event"
UTILISATION_PREFIX = "Utilisation/"
SPARK_SERIES = {"Spindle/1/Load": "spindle load", "Feed/Actual": "feed rate"}
STATE_INPUTS = frozenset((EXECUTION, AVAILABILITY, RUN, ALARM, EMERGENCY))

EXECUTION_BANDS = {"ACTIVE": Band.RUNNING, "FEED_HOLD": Band.FEED_HOLD, "INTERRUPTED": Band.FEED_HOLD,
                   "READY": Band.IDLE, "STOPPED": Band.IDLE, "PROGRAM_STOPPED": Band.IDLE,
                   "PROGRAM_COMPLETED": Band.IDLE, "WAIT": Band.IDLE, "OPTIONAL_STOP": Band.IDLE,
                   "UNAVAILABLE": Band.UNKNOWN}  # a run code the derivation does not know
RUN_BANDS = {"START": Band.RUNNING, "MSTR": Band.RUNNING, "HOLD": Band.FEED_HOLD, "STOP": Band.IDLE,
             "RESET": Band.IDLE}
# Status/Alarm texts that are warnings (battery, fan): the machine still runs.
ALARM_WARNINGS = frozenset(("", "BAT", "FAN"))

HOUR_S = 3600.0
DAY_MINUTES = 1440
DAY_RING = DAY_MINUTES + 1  # 24 h of closed minutes, and the slot of the minute being accumulated
HOUR_TRANSITIONS = 720  # one change every 5 s on average; a faster flapper loses the start of its hour
SPARK_STEP_S = 30.0
SPARK_POINTS = int(HOUR_S / SPARK_STEP_S)
ALARMS_KEPT = 100


def band_of(inputs: Mapping[str, object]) -> Band:
    """The band for the latest status values: availability, emergency, alarm, then the execution state."""
    if inputs.get(AVAILABILITY) == "UNAVAILABLE":
        return Band.OFFLINE
    if inputs.get(EMERGENCY) is True:
        return Band.EMERGENCY
    alarm = inputs.get(ALARM)
    if isinstance(alarm, str) and alarm not in ALARM_WARNINGS:
        return Band.ALARM
    execution = inputs.get(EXECUTION)
    if isinstance(execution, str):
        return EXECUTION_BANDS.get(execution, Band.UNKNOWN)
    run = inputs.get(RUN)
    return RUN_BANDS.get(run, Band.UNKNOWN) if isinstance(run, str) else Band.UNKNOWN


def _dominant(seconds: Sequence[float]) -> Band:
    """The band that filled most of a minute; a tie goes to the more troubled one."""
    best = max(range(len(seconds)), key=lambda code: (seconds[code], -TROUBLE_RANK[Band(code)]))
    return Band(best)


class DayStrip:
    """The last 24 h as one band per minute (the one that filled most of it), in a ring of bytes."""

    def __init__(self, start: float) -> None:
        self.slots = bytearray(DAY_RING)  # Band.UNKNOWN everywhere
        self.minute = int(start // 60)  # the minute being accumulated
        self.mark = start  # accumulated up to here
        self.band = Band.UNKNOWN
        self.seconds = [0.0] * len(Band)

    def advance(self, now: float) -> None:
        """Account the current band up to `now`, closing every minute passed."""
        minute = int(now // 60)
        if minute > self.minute:
            end = (self.minute + 1) * 60.0
            self.seconds[self.band] += max(0.0, end - self.mark)
            self.slots[self.minute % DAY_RING] = _dominant(self.seconds)
            for m in range(self.minute + 1, min(minute, self.minute + 1 + DAY_RING)):
                self.slots[m % DAY_RING] = self.band  # whole minutes in one band
            self.seconds = [0.0] * len(Band)
            self.minute, self.mark = minute, minute * 60.0
        if now > self.mark:
            self.seconds[self.band] += now - self.mark
            self.mark = now

    def set(self, now: float, band: Band) -> None:
        self.advance(now)
        self.band = band

    def bands(self, start: float, end: float) -> list[tuple[float, float, Band]]:
        """(start, end, band) runs covering [start, end): closed minutes, then the current one as it is now."""
        self.advance(end)
        first = max(int(start // 60), self.minute - DAY_MINUTES)
        runs: list[tuple[float, float, Band]] = []
        if first * 60.0 > start:
            runs.append((start, first * 60.0, Band.UNKNOWN))
        for m in range(first, self.minute):
            _extend(runs, max(start, m * 60.0), (m + 1) * 60.0, Band(self.slots[m % DAY_RING]))
        _extend(runs, max(start, self.minute * 60.0), end, _dominant(self.seconds) if any(self.seconds) else self.band)
        return runs

    def seconds_in(self, band: Band, start: float, now: float) -> float:
        """Seconds (to the minute) spent in `band` from `start` (within the last 24 h) to `now`; counted
        with bytearray.count, so the fleet overview can ask it of 1,000 machines."""
        self.advance(now)
        first = max(int(start // 60), self.minute - DAY_MINUTES)
        minutes = 0
        if first < self.minute:
            a, b = first % DAY_RING, self.minute % DAY_RING
            count = self.slots.count
            minutes = count(band, a, b) if a < b else count(band, a) + count(band, 0, b)
        return minutes * 60.0 + self.seconds[band]


def _extend(runs: list[tuple[float, float, Band]], start: float, end: float, band: Band) -> None:
    if end <= start:
        return
    if runs and runs[-1][2] is band and runs[-1][1] >= start:
        runs[-1] = (runs[-1][0], end, band)
    else:
        runs.append((start, end, band))


class HourBands:
    """The last hour's transitions, exact: parallel arrays of start time and band."""

    def __init__(self) -> None:
        self.starts = array("d")
        self.codes = bytearray()

    def set(self, now: float, band: Band) -> None:
        if self.codes and self.codes[-1] == band:
            return
        self.starts.append(now)
        self.codes.append(band)
        self._prune(now)

    def _prune(self, now: float) -> None:
        """Drop transitions whose band ended more than an hour ago, and any beyond the cap."""
        keep_from = 0
        while keep_from + 1 < len(self.starts) and self.starts[keep_from + 1] <= now - HOUR_S:
            keep_from += 1
        keep_from = max(keep_from, len(self.starts) - HOUR_TRANSITIONS)
        if keep_from:
            del self.starts[:keep_from]
            del self.codes[:keep_from]

    def bands(self, start: float, end: float) -> list[tuple[float, float, Band]]:
        runs: list[tuple[float, float, Band]] = []
        if not self.starts or self.starts[0] > start:
            _extend(runs, start, min(end, self.starts[0]) if self.starts else end, Band.UNKNOWN)
        for i, begin in enumerate(self.starts):
            until = self.starts[i + 1] if i + 1 < len(self.starts) else end
            _extend(runs, max(start, begin), min(end, until), Band(self.codes[i]))
        return runs


class Sparkline:
    """One series over the last hour, per 30 s step: the time-weighted mean and the peak. Values come by
    exception, so a value counts for as long as it was held; NaN where there was none (offline, a refused
    read). The mean shows how hard the machine worked, the peak a spike the mean would hide."""

    def __init__(self) -> None:
        self.means = array("d", [math.nan] * SPARK_POINTS)
        self.peaks = array("d", [math.nan] * SPARK_POINTS)
        self.step: int | None = None  # the step being filled
        self.last: float | None = None
        self.mark = 0.0  # the current step is accounted up to here
        self.area = 0.0  # value x seconds in the current step
        self.covered = 0.0  # seconds of the current step with a value

    def _account(self, until: float) -> None:
        if self.last is not None and until > self.mark:
            self.area += self.last * (until - self.mark)
            self.covered += until - self.mark
        self.mark = max(self.mark, until)

    def _advance(self, now: float) -> None:
        """Close every step before `now`'s (whole steps in between hold the last value), account up to now."""
        step = int(now // SPARK_STEP_S)
        if self.step is None:
            self.step, self.mark = step, now
        while self.step < step:
            self._account((self.step + 1) * SPARK_STEP_S)
            slot = self.step % SPARK_POINTS
            self.means[slot] = self.area / self.covered if self.covered > 0 else math.nan
            self.step += 1
            self.area = self.covered = 0.0
            self.peaks[self.step % SPARK_POINTS] = math.nan if self.last is None else self.last
            if step - self.step > SPARK_POINTS:  # a long quiet spell: every step in the hour held the last value
                held = math.nan if self.last is None else self.last
                self.means[:] = array("d", [held] * SPARK_POINTS)
                self.peaks[:] = array("d", [held] * SPARK_POINTS)
                self.step, self.mark = step, step * SPARK_STEP_S
        self._account(now)

    def record(self, now: float, value: float | None) -> None:
        self._advance(now)
        assert self.step is not None
        slot = self.step % SPARK_POINTS
        if value is not None and not value <= self.peaks[slot]:  # NaN compares false: the first value is a peak
            self.peaks[slot] = value
        self.last = value

    def series(self, now: float, steps: int = SPARK_POINTS) -> tuple[list[float | None], list[float | None]]:
        """The last `steps` steps, oldest first: (means, peaks), None where there was no value."""
        if self.step is None:
            return [None] * steps, [None] * steps
        self._advance(now)
        newest = self.step
        held = math.nan if self.last is None else self.last  # a step just begun shows the value held
        self.means[newest % SPARK_POINTS] = self.area / self.covered if self.covered > 0 else held
        window = range(newest - steps + 1, newest + 1)
        means = [self.means[s % SPARK_POINTS] for s in window]
        peaks = [self.peaks[s % SPARK_POINTS] for s in window]
        return [None if math.isnan(v) else v for v in means], [None if math.isnan(v) else v for v in peaks]

    def points(self, now: float) -> list[float | None]:
        """The last hour's means, oldest first."""
        return self.series(now)[0]


@dataclass(frozen=True, slots=True)
class AlarmNote:
    """One alarm raise or clear as the page lists it (epoch seconds of the CNC's timestamp)."""

    at: float
    event: str
    number: int
    type: object
    message: str


@dataclass(slots=True)
class MachineTrend:
    """Everything the page draws for one machine."""

    first_seen: float
    band: Band = Band.UNKNOWN
    since: float = 0.0
    inputs: dict[str, object] = field(default_factory=dict)
    day: DayStrip = field(init=False)
    hour: HourBands = field(default_factory=HourBands)
    sparks: dict[str, Sparkline] = field(default_factory=lambda: {name: Sparkline() for name in SPARK_SERIES})
    alarms: deque[AlarmNote] = field(default_factory=lambda: deque(maxlen=ALARMS_KEPT))
    utilisation: dict[str, object] = field(default_factory=dict)  # Utilisation/<STATE> seconds, Utilisation/Day

    def __post_init__(self) -> None:
        self.day = DayStrip(self.first_seen)
        self.since = self.first_seen

    def set_band(self, now: float, band: Band) -> None:
        self.day.set(now, band)
        self.hour.set(now, band)
        if band is not self.band:
            self.band, self.since = band, now


class TrendRecorder:
    """A DeviceSink that records, for the plant page, what the publisher is sent. Never raises on odd values."""

    def __init__(self, clock: Callable[[], float] = time.time) -> None:
        self.clock = clock
        self.machines: dict[str, MachineTrend] = {}

    def machine(self, device_id: str) -> MachineTrend | None:
        return self.machines.get(device_id)

    def forget(self, device_id: str) -> None:
        """A machine removed from the config: its history goes with it."""
        self.machines.pop(device_id, None)

    def _trend(self, device_id: str, now: float) -> MachineTrend:
        trend = self.machines.get(device_id)
        if trend is None:
            trend = self.machines[device_id] = MachineTrend(now)
        return trend

    def observe(self, device_id: str, samples: Sequence[Sample], birth: bool = False) -> None:
        now = self.clock()
        trend = self._trend(device_id, now)
        if birth:
            trend.inputs.pop(AVAILABILITY, None)  # the session is back: the birth says the rest
        state_changed = birth
        kinds = _KINDS
        for sample in samples:
            name = sample.name
            kind = kinds.get(name)
            if kind is None:
                kind = _kind_of(name)
            if not kind:  # most of a tick's values (positions, speeds, macros): nothing a trend shows
                continue
            if kind == _STATE:
                trend.inputs[name] = sample.value
                state_changed = True
            elif kind == _SPARK:
                value = sample.value
                trend.sparks[name].record(now, float(value) if isinstance(value, int | float) else None)
            elif kind == _UTILISATION:
                trend.utilisation[name[len(UTILISATION_PREFIX):]] = sample.value
            else:
                note = _alarm_note(sample)
                if note is not None:
                    trend.alarms.append(note)
        if state_changed:
            trend.set_band(now, band_of(trend.inputs))

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        self.observe(device_id, samples, birth=True)

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        self.observe(device_id, samples)

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        self.observe(device_id, events)

    async def device_offline(self, device_id: str) -> None:
        now = self.clock()
        trend = self._trend(device_id, now)
        trend.inputs[AVAILABILITY] = "UNAVAILABLE"
        trend.set_band(now, Band.OFFLINE)
        for spark in trend.sparks.values():
            spark.record(now, None)


_OTHER, _STATE, _SPARK, _UTILISATION, _EVENT = range(5)
KINDS_LIMIT = 65536  # distinct metric names classified and kept; a fleet of a few models has a few hundred
_KINDS: dict[str, int] = {}  # metric name -> what observe does with it (asked once per name, not per value)


def _kind_of(name: str) -> int:
    kind = (_STATE if name in STATE_INPUTS else _SPARK if name in SPARK_SERIES
            else _UTILISATION if name.startswith(UTILISATION_PREFIX) else _EVENT if name == ALARM_EVENT else _OTHER)
    if len(_KINDS) >= KINDS_LIMIT:
        _KINDS.clear()
    _KINDS[name] = kind
    return kind


def _alarm_note(sample: Sample) -> AlarmNote | None:
    """An Alarm/Event JSON payload as an AlarmNote; None for one that does not parse (never raises)."""
    try:
        event = json.loads(str(sample.value))
        return AlarmNote(float(event.get("timestamp_ms", sample.timestamp_ms)) / 1000.0, str(event["event"]),
                         int(event["number"]), event.get("type"), str(event.get("message") or ""))
    except (ValueError, KeyError, TypeError, AttributeError):
        return None
