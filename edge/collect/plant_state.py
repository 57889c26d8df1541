"""The poller's one hook for what the plant looks at: Availability, and utilisation fed by the derived state.

`Status/Execution` and `Status/ControllerMode` are plain values of the status read (edge.collect.plan calls
edge.collect.execution); this module adds what needs memory across ticks and sessions:
`Status/Availability` (AVAILABLE in the birth, UNAVAILABLE published just before the device goes offline) and
the `Utilisation/...` counters (edge.collect.utilisation), told of a new state only when the status word
changed, published on a change of state and once a minute, saved to state_dir every 5 minutes and at close.

UNAVAILABLE and the OFFLINE switch are stamped with the gateway's estimate of CNC time at the moment the poller
found the session broken (the CNC cannot stamp its own absence; the true drop lies between the last answer and
that moment, at most one request timeout earlier).
"""

from __future__ import annotations

import asyncio
import logging
import time
import zlib
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

from edge.collect import utilisation as ut
from edge.collect.execution import AVAILABILITY, AVAILABLE, OFFLINE, UNAVAILABLE, UNKNOWN, derive
from edge.focas.model import StatInfo
from edge.samples import MetricSpec, Quality, Sample, new_sample

log = logging.getLogger(__name__)

SPECS: tuple[MetricSpec, ...] = (AVAILABILITY, *ut.SPECS)
MINUTE_S = 60.0
# A save (atomic write, two fsyncs) costs ~0.7 ms of CPU: every 5th minute keeps it near 0.2 µs per machine-cycle
# at 10 Hz; a crash loses at most 5 minutes to UNKNOWN (a stop or reload saves at once).
SAVE_EVERY_MINUTES = 5


class PlantState:
    """One device's availability and utilisation counters (created with its poller, saved at its close)."""

    def __init__(self, device_id: str, zone: ZoneInfo, state_dir: Path, now_ms: int | None = None) -> None:
        self.device_id = device_id
        self.store = ut.UtilisationStore(state_dir, device_id)
        now_ms = _wall_ms() if now_ms is None else now_ms
        self.counter = self._restore(zone, now_ms)
        self._saves = 0
        # Each device publishes (and saves) at its own second of the minute: a fleet does not write at once.
        self._phase_s = zlib.crc32(device_id.encode()) % 60_000 / 1000

    def _restore(self, zone: ZoneInfo, now_ms: int) -> ut.UtilisationCounter:
        try:
            saved = self.store.load()
            if saved is not None:
                return ut.UtilisationCounter.restored(zone, saved, now_ms)
        except (OSError, ValueError) as exc:  # json.JSONDecodeError is a ValueError
            log.warning("utilisation file unreadable, today's counters start again machine=%s file=%s error=%s",
                        self.device_id, self.store.path, exc)
        return ut.UtilisationCounter.first_start(zone, now_ms)

    # ---- what the poller tells it ----------------------------------------------------------------------
    def birth_samples(self, at_ms: int) -> list[Sample]:
        """AVAILABLE and every counter, for the device's birth."""
        ended = self.counter.advance(at_ms)
        return [*_ended_samples(ended), Sample(AVAILABILITY.name, AVAILABLE, AVAILABILITY.type, at_ms),
                *self.counter.totals().samples()]

    def status(self, stat: StatInfo, at_ms: int) -> list[Sample]:
        """A new status word: the counters to publish when it means another state (usually nothing)."""
        state = derive(stat).counts_as
        if state == self.counter.state:
            return []
        return self._switch(state, at_ms)

    def status_failed(self, at_ms: int) -> list[Sample]:
        """The status read failed: nobody knows the state until it answers again."""
        return [] if self.counter.state == UNKNOWN else self._switch(UNKNOWN, at_ms)

    def offline(self, at_ms: int) -> list[Sample]:
        """The session is down: UNAVAILABLE and the counters, to publish before the device's death."""
        samples = self._switch(OFFLINE, at_ms) if self.counter.state != OFFLINE else []
        return [Sample(AVAILABILITY.name, UNAVAILABLE, AVAILABILITY.type, at_ms), *samples]

    def minute(self, at_ms: int) -> list[Sample]:
        """The minute publish: the current state counted up to now (a new day: every counter)."""
        state = self.counter.state
        return self._moved(state, self.counter.advance(at_ms), at_ms)

    def _switch(self, state: str, at_ms: int) -> list[Sample]:
        """Only the counter of the state that ended moved (at midnight: every counter, from zero)."""
        ended_state = self.counter.state
        return self._moved(ended_state, self.counter.switch(state, at_ms), at_ms)

    def _moved(self, state: str, ended: list[ut.DayTotals], at_ms: int) -> list[Sample]:
        if ended:
            return [*_ended_samples(ended), *self.counter.totals().samples()]
        spec = ut.COUNTERS[state]
        return [new_sample(spec.name, round(self.counter.seconds[state], 3), spec.type, at_ms, Quality.GOOD)]

    # ---- the minute and saving (edge.collect.minute_timers calls them) ---------------------------------
    async def save_in_thread(self) -> None:
        """Save a snapshot of the counters, the file written off the event loop (raises OSError)."""
        sequence, data = self._snapshot()
        await asyncio.to_thread(self.store.save, sequence, data)

    def next_delay_s(self, wall_s: float, now_ms: int) -> float:
        """Seconds to this device's next minute mark or the next local midnight, whichever is first."""
        to_minute = MINUTE_S - (wall_s - self._phase_s) % MINUTE_S
        to_midnight = (self.counter.next_midnight_ms - now_ms) / 1000
        return max(0.05, min(to_minute, to_midnight))

    def close(self, at_ms: int) -> None:
        """Count up to now and save (a reload or restart goes on from here; the gap counts as UNKNOWN)."""
        self.counter.advance(at_ms)
        try:
            self.store.save(*self._snapshot())
        except OSError as exc:
            log.warning("utilisation not saved machine=%s file=%s error=%s", self.device_id, self.store.path, exc)

    def _snapshot(self) -> tuple[int, dict[str, Any]]:
        self._saves += 1
        return self._saves, self.counter.to_json()


def _ended_samples(ended: list[ut.DayTotals]) -> list[Sample]:
    return [sample for day in ended for sample in day.samples()]


def _wall_ms() -> int:
    return int(time.time() * 1000)
