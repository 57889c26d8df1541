"""One machine's CNC clock as the poller feeds it: readings into the tracker, the log lines, the Clock/* samples.

The poller does the network reads (the tick's clock subpacket, and the clock-only reads edge.collect.clock_probe
times); everything it then does with a clock answer lives here, so the poll loop stays about polling. Failure
bookkeeping (counting a failed ReadClock, clearing it when it answers) stays with the poller's other functions.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from datetime import datetime
from zoneinfo import ZoneInfo

from edge.collect import plan as pl
from edge.collect.clock import MAX_DRIFT_RATE, ClockTracker, cnc_to_utc_seconds
from edge.collect.clock_probe import ClockProbes, ProbeCalendar
from edge.samples import Quality, Sample

log = logging.getLogger(__name__)

# One per process, which is one gateway: its machines' narrowing reads share the bins (clock_probe).
FLEET_CALENDAR = ProbeCalendar()

_NOTHING = object()  # no reading yet (compares unequal to any answer)

Report = Callable[..., Sample | None]  # ChangeDetector.report: a sample when the value changed


class ClockFeed:
    """The tracker, the clock-only read timer and what was last read and logged, for one machine."""

    def __init__(self, machine_id: str, zone: ZoneInfo, max_skew_s: float) -> None:
        self.machine_id = machine_id
        self.tracker = ClockTracker(zone, max_skew_s, drift_rate=MAX_DRIFT_RATE)
        self.probes = ClockProbes(self.tracker, calendar=FLEET_CALENDAR)
        self.news = False  # a clock-only read (or a slew) moved the clock: the next tick publishes it
        self._reading: object = _NOTHING  # the CNC clock value of the last answer (unchanged within a second)
        self._epoch = 0.0  # that value as epoch seconds
        self._mode_logged: bool | None = None  # the clock mode last announced in the log
        self._offered: tuple[object, ...] | None = None  # the Clock/* values last offered to change detection

    def new_session(self) -> None:
        """A fresh session answers a fresh object even for the same second, and has a fresh change detector."""
        self._reading = _NOTHING
        self._offered = None

    def is_new_reading(self, result: object) -> bool:
        """True for a clock value other than the last one (the poller then clears a failing ReadClock)."""
        return result is not self._reading and isinstance(result, datetime)

    def observe(self, result: object, mid_mono: float, mid_wall: float, half_rtt: float) -> bool:
        """Feed one clock answer to the tracker; False when it changed nothing about the clock.

        The CNC clock has one-second resolution, so most ticks read the same second again (the client
        hands it back as the same object): such a reading is converted once and observed only when it
        tightens the offset interval (ClockTracker.narrows), which after the first seconds is rare. An
        answer that is not a time (an error) forgets the last reading and counts as news (the poller
        counts the error).
        """
        tracker = self.tracker
        if result is self._reading:
            if not tracker.narrows(self._epoch, mid_mono, half_rtt):
                return False
        elif isinstance(result, datetime):
            self._reading, self._epoch = result, cnc_to_utc_seconds(result, tracker.zone)
        else:
            self._reading = _NOTHING
            return True
        steps = tracker.steps
        tracker.observe_epoch(self._epoch, mid_mono, mid_wall, half_rtt)
        if tracker.steps != steps:
            self._log_step()
        using_gateway = tracker.use_gateway_time
        if using_gateway != self._mode_logged:
            if using_gateway:
                log.warning("using gateway time machine=%s reason=%s", self.machine_id, tracker.reason)
            else:
                log.info("using CNC time machine=%s skew=%.3fs", self.machine_id, tracker.skew_s or 0.0)
            self._mode_logged = using_gateway
        return True

    def _log_step(self) -> None:
        step = self.tracker.last_step_s or 0.0
        follow = ("stamps slow to half speed until they meet it, never earlier than one already sent" if step < 0
                  else "stamps follow it at once")
        log.warning("CNC clock stepped machine=%s step=%+.1fs skew=%.1fs: offset re-synced, %s", self.machine_id,
                    step, self.tracker.skew_s or 0.0, follow)

    def samples(self, timestamp: int, mid_mono: float, report: Report, samples: list[Sample]) -> None:
        """Append the Clock/* metrics that changed (skew, gateway-time flag, offset uncertainty, synchronised).

        Values equal to the ones offered last time are not offered again: `report` would find each unchanged
        (only this feed reports these names to its session's detector, and `new_session` forgets what was
        offered). Most new CNC seconds move none of them; at 1 Hz that is every tick."""
        tracker = self.tracker
        skew = tracker.skew_s
        uncertainty, slew_lag, synchronised = tracker.stamp_quality_at(mid_mono)
        skew_ms = round(skew, 3) if skew is not None else None
        # Whole milliseconds, rounded up: still a bound, and it moves every ~10 s as readings age, not every tick
        uncertainty_ms = float(math.ceil(uncertainty * 1000)) if uncertainty is not None else None
        offered = (skew_ms, tracker.use_gateway_time, uncertainty_ms, synchronised)
        if offered != self._offered:
            self._offered = offered
            for sample in (
                report(pl.CLOCK_SKEW.name, skew_ms, pl.CLOCK_SKEW.type, timestamp,
                       Quality.GOOD if skew is not None else Quality.BAD),
                report(pl.CLOCK_GATEWAY.name, offered[1], pl.CLOCK_GATEWAY.type, timestamp),
                report(pl.CLOCK_UNCERTAINTY.name, uncertainty_ms, pl.CLOCK_UNCERTAINTY.type, timestamp,
                       Quality.GOOD if uncertainty is not None else Quality.BAD),
                report(pl.CLOCK_SYNCHRONISED.name, offered[3], pl.CLOCK_SYNCHRONISED.type, timestamp),
            ):
                if sample is not None:
                    samples.append(sample)
        self.news = slew_lag > 0.0  # while stamps slew, Synchronised may turn true

