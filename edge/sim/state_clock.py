"""The simulated CNC's wall clock: real time plus an offset, shown in the CNC's own zone.

A control's clock is set by hand and drifts, so it is modelled as an offset from the gateway's real
time (the injected `time_source`) rendered in the CNC's zone as naive local time, which is what both
wire forms carry. Setting the clock moves the offset; real time never changes.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime, tzinfo
from zoneinfo import ZoneInfo

from edge.focas.errors import EW_DATA, cnc_error
from edge.sim.state_writes import WriteLog

CLOCK_MACRO_MODULO = 1000.0  # a macro holds about nine digits: seconds modulo 1000 with milliseconds


def clock_macro_value(epoch_s: float) -> float:
    """What the clock macro reads at a CNC time (epoch seconds): seconds modulo 1000, to the millisecond."""
    return round(epoch_s % CLOCK_MACRO_MODULO, 3)


def clock_macro_error(stamp_s: float, value: float) -> float:
    """A source timestamp (epoch seconds) minus the CNC clock a clock macro `value` recorded, in seconds
    (-500..500: the macro wraps every 1000 s)."""
    return (stamp_s - value + CLOCK_MACRO_MODULO / 2) % CLOCK_MACRO_MODULO - CLOCK_MACRO_MODULO / 2


def zone(name: str | tzinfo) -> tzinfo:
    return ZoneInfo(name) if isinstance(name, str) else name


class CncClock:
    """The clock of one machine; MachineState holds the lock around every call (see edge.sim.state)."""

    def __init__(self, time_source: Callable[[], float], timezone: str | tzinfo, clock_offset: float,
                 writes: WriteLog) -> None:
        self._time = time_source
        self.tz = zone(timezone)
        self.offset = float(clock_offset)  # seconds the CNC clock runs ahead of real time (negative: behind)
        self._writes = writes

    def local_at(self, real: float) -> datetime:
        return datetime.fromtimestamp(real + self.offset, self.tz).replace(tzinfo=None)

    def clock(self) -> datetime:
        return self.local_at(self._time())

    def epoch(self) -> float:
        """The CNC clock as epoch seconds, to the microsecond (what the clock macro reads)."""
        return self._time() + self.offset

    def clock_utc(self) -> datetime:
        return datetime.fromtimestamp(self._time() + self.offset, UTC)

    def set_clock(self, local: datetime, protocol: str) -> None:
        before = self.clock()
        aware = local.replace(tzinfo=self.tz) if local.tzinfo is None else local
        self.offset = aware.timestamp() - self._time()
        self._writes.add(protocol, "clock", before.isoformat(), local.isoformat())

    def set_time_of_day(self, hour: int, minute: int, second: int, protocol: str) -> None:
        if not (0 <= hour < 24 and 0 <= minute < 60 and 0 <= second < 60):
            raise cnc_error(EW_DATA, "cnc_settimer", message=f"time {hour}:{minute}:{second} is not valid")
        self.set_clock(self.clock().replace(hour=hour, minute=minute, second=second, microsecond=0), protocol)
