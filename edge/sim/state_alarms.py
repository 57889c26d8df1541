"""The simulated CNC's alarms: those active now, and the history ring a control keeps.

Alarms come from two sources: the cycle (machines with ``CycleSpec.alarm_every`` > 0 raise one between
parts every that many cycles and clear it a few seconds later) and by hand (tests, the admin endpoint).
Every alarm enters the history ring (250 entries, newest first) stamped with the CNC's local wall-clock
time; a fresh machine already has a few past alarms over the previous days.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from datetime import UTC, datetime

from edge.focas.model import ActiveAlarm, AlarmHistoryEntry
from edge.sim.state_clock import CncClock
from edge.sim.state_program import CycleSpec

ALARM_HISTORY_SIZE = 250

# cnc_rdalmmsg alarm type numbers (30i): bit n of the alarm-status word is type n.
ALARM_TYPES = {"SW": 0, "PW": 1, "IO": 2, "PS": 3, "OT": 4, "OH": 5, "SV": 6, "SR": 7, "MC": 8,
               "SP": 9, "DS": 10, "IE": 11, "BG": 12, "SN": 13, "EX": 15}

# Alarms the cycle raises between parts (number, type, axis, message), chosen in turn.
CYCLE_ALARMS: tuple[tuple[int, int, int, str], ...] = (
    (1004, ALARM_TYPES["EX"], 0, "COOLANT LEVEL LOW"),
    (500, ALARM_TYPES["OT"], 1, "OVER TRAVEL ( +1 )"),
    (1010, ALARM_TYPES["EX"], 0, "DOOR INTERLOCK OPEN"),
    (700, ALARM_TYPES["OH"], 0, "OVERHEAT: CONTROL UNIT"),
    (436, ALARM_TYPES["SV"], 2, "SOFTTHERMAL (OVC)"),
)


@dataclass(frozen=True, slots=True)
class AlarmEvent:
    """An alarm occurrence as the CNC records it: local wall-clock time plus the real instant."""

    local_time: datetime  # naive, CNC wall clock
    utc_time: datetime  # aware, the real instant (for tests)
    number: int
    type: int
    axis: int
    message: str

    def entry(self) -> AlarmHistoryEntry:
        """The history entry as the wire carries it: the CNC's wall-clock fields, labelled UTC.

        Both wire forms carry year..second with no zone; decoders take them as UTC (seed 000), so an
        encode/decode round trip of this entry is exact. The collector converts with the machine's zone.
        """
        return AlarmHistoryEntry(occurred=self.local_time.replace(tzinfo=UTC), axis_no=self.axis,
                                 alm_type=self.type, alm_no=self.number, message=self.message)


class Alarms:
    """One machine's active alarms and history; MachineState holds the lock around every call and
    advances the cycle first (see edge.sim.state)."""

    def __init__(self, clock: CncClock) -> None:
        self._clock = clock  # stamps the history with the CNC's local time
        self.history: deque[AlarmEvent] = deque(maxlen=ALARM_HISTORY_SIZE)
        self.manual: list[ActiveAlarm] = []
        self.cycle_alarm: ActiveAlarm | None = None

    def any_active(self) -> bool:
        return bool(self.manual) or self.cycle_alarm is not None

    def active(self, max_count: int) -> list[ActiveAlarm]:
        alarms = ([self.cycle_alarm] if self.cycle_alarm else []) + self.manual
        return alarms[: max(0, max_count)]

    def events(self, depth: int) -> list[AlarmEvent]:
        depth = min(max(depth, 1), ALARM_HISTORY_SIZE)
        return list(self.history)[:depth]

    def raise_alarm(self, number: int, type: int, axis: int, message: str, real: float) -> ActiveAlarm:
        alarm = ActiveAlarm(number, type, axis, message or f"ALARM {number}")
        self.manual = [a for a in self.manual if a.number != number] + [alarm]
        self.record(alarm, real)
        return alarm

    def clear(self, number: int | None) -> None:
        if number is None:
            self.manual = []
            self.cycle_alarm = None
        else:
            self.manual = [a for a in self.manual if a.number != number]
            if self.cycle_alarm and self.cycle_alarm.number == number:
                self.cycle_alarm = None

    def record(self, alarm: ActiveAlarm, real: float) -> None:
        self.history.appendleft(AlarmEvent(
            local_time=self._clock.local_at(real).replace(microsecond=0),
            utc_time=datetime.fromtimestamp(real, UTC),
            number=alarm.number, type=alarm.type, axis=alarm.axis, message=alarm.message))

    def seed_history(self, t0: float, seed: int) -> None:
        """A few past alarms over the previous days, so a fresh machine already has a history."""
        step = 6 * 3600 + 17 * 60 + 13 * (seed % 5)
        for i in range(12, 0, -1):
            number, atype, axis, message = CYCLE_ALARMS[(i + seed) % len(CYCLE_ALARMS)]
            self.record(ActiveAlarm(number, atype, axis, message), t0 - i * step)

    def replay(self, cycle: CycleSpec, start: float, end: float, t0: float, phase: float) -> None:
        """Raise/clear the cycle alarms whose moments fall in (start, end]; at most a ring's worth.

        start and end are cycle times; real time = t0 + cycle time - phase.
        """
        length, every = cycle.length, cycle.alarm_every
        first = max(0, math.floor(start / length) - 1)
        last = math.floor(end / length)
        first = max(first, last - every * (ALARM_HISTORY_SIZE + 1))
        for k in range(first, last + 1):
            if k % every != every - 1:
                continue
            raised = k * length + cycle.cut_seconds + 0.5
            cleared = raised + min(cycle.alarm_seconds, cycle.idle_seconds - 0.6)
            number, atype, axis, message = CYCLE_ALARMS[(k // every) % len(CYCLE_ALARMS)]
            if start < raised <= end:
                alarm = ActiveAlarm(number, atype, axis, message)
                self.cycle_alarm = alarm
                self.record(alarm, t0 + raised - phase)
            if start < cleared <= end:
                self.cycle_alarm = None
