"""Utilisation: seconds a machine (path) spent in each state since local midnight, kept across restarts.

A shift lead asks "how long was it cutting today"; the gateway answers with one counter per state
(`Utilisation/<STATE>`, edge.collect.execution.UTILISATION_STATES) and `Utilisation/Day`, the local date they
count. Counters move only at a change of state and at the minute publish (never per poll tick), roll over at
local midnight in the machine's `timezone`, and survive a restart or reload in
`<state_dir>/utilisation/<device>.json` (written whole, edge.statefile). Time the gateway did not run (from
the last save to the restart, or from midnight on the very first start) counts as UNKNOWN, not as the state
the machine was last seen in: nobody saw it.

Times are epoch milliseconds: the CNC's stamps for changes seen in a poll, the gateway's CNC-time estimate
otherwise. A time earlier than what is already counted counts nothing (a clock that stepped back).
"""

from __future__ import annotations

import json
import logging
import threading
from dataclasses import dataclass
from datetime import date, datetime, timedelta
from datetime import time as wall_time
from pathlib import Path
from typing import Any
from urllib.parse import quote
from zoneinfo import ZoneInfo

from edge.collect.execution import OFFLINE, UNKNOWN, UTILISATION_STATES
from edge.samples import MetricSpec, MetricType, Sample
from edge.statefile import write_atomically

log = logging.getLogger(__name__)

DAY = MetricSpec("Utilisation/Day", MetricType.STRING, description="local date the Utilisation counters count")
COUNTERS = {state: MetricSpec(f"Utilisation/{state}", MetricType.DOUBLE, "s",
                              description=f"seconds in {state} since local midnight")
            for state in UTILISATION_STATES}
SPECS: tuple[MetricSpec, ...] = (*COUNTERS.values(), DAY)
FORMAT = 1  # the state file's format version


@dataclass(frozen=True, slots=True)
class DayTotals:
    """One local day's counters as of `at_ms` (seconds per state)."""

    day: date
    seconds: dict[str, float]
    at_ms: int

    def samples(self) -> list[Sample]:
        out = [Sample(spec.name, round(self.seconds.get(state, 0.0), 3), spec.type, self.at_ms)
               for state, spec in COUNTERS.items()]
        out.append(Sample(DAY.name, self.day.isoformat(), DAY.type, self.at_ms))
        return out


class UtilisationCounter:
    """The counters of one device: the state it is in since `since_ms`, and today's seconds per state."""

    def __init__(self, zone: ZoneInfo, state: str, since_ms: int, day: date | None = None,
                 seconds: dict[str, float] | None = None) -> None:
        self.zone = zone
        self.state = state
        self.since_ms = since_ms
        self.day = day or local_day(since_ms, zone)
        self.seconds: dict[str, float] = dict.fromkeys(UTILISATION_STATES, 0.0)
        self.seconds.update(seconds or {})
        self.next_midnight_ms = midnight_after(self.day, zone)

    @classmethod
    def first_start(cls, zone: ZoneInfo, now_ms: int) -> UtilisationCounter:
        """No saved day: from local midnight to now nobody watched (UNKNOWN), OFFLINE from now."""
        day = local_day(now_ms, zone)
        counter = cls(zone, UNKNOWN, midnight_after(day - timedelta(days=1), zone), day)
        counter.switch(OFFLINE, now_ms)
        return counter

    def advance(self, at_ms: int) -> list[DayTotals]:
        """Count up to `at_ms` in the current state; the days that ended on the way (their final totals)."""
        ended: list[DayTotals] = []
        while at_ms >= self.next_midnight_ms:
            midnight = self.next_midnight_ms
            self._add(midnight)
            ended.append(DayTotals(self.day, dict(self.seconds), midnight - 1))
            self.day += timedelta(days=1)
            self.seconds = dict.fromkeys(UTILISATION_STATES, 0.0)
            self.next_midnight_ms = midnight_after(self.day, self.zone)
        self._add(at_ms)
        return ended

    def switch(self, state: str, at_ms: int) -> list[DayTotals]:
        """The machine is in `state` from `at_ms` on (the time before counts to the state it was in)."""
        ended = self.advance(at_ms)
        self.state = state
        return ended

    def totals(self) -> DayTotals:
        return DayTotals(self.day, dict(self.seconds), self.since_ms)

    def _add(self, until_ms: int) -> None:
        if until_ms > self.since_ms:
            self.seconds[self.state] = self.seconds.get(self.state, 0.0) + (until_ms - self.since_ms) / 1000
            self.since_ms = until_ms

    # ---- the state file ------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "day": self.day.isoformat(), "since_ms": self.since_ms,
                "state": self.state, "seconds": {k: round(v, 3) for k, v in self.seconds.items() if v}}

    @classmethod
    def restored(cls, zone: ZoneInfo, data: Any, now_ms: int) -> UtilisationCounter:
        """The saved counters, the time since the save counted as UNKNOWN, OFFLINE from `now_ms`.
        ValueError names what is wrong with `data`."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ValueError(f"not a utilisation file of format {FORMAT}")
        try:
            day = date.fromisoformat(str(data["day"]))
            since_ms = int(data["since_ms"])
            seconds = {str(k): float(v) for k, v in dict(data["seconds"]).items()}
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"bad field: {exc!r}") from None
        counter = cls(zone, UNKNOWN, since_ms, day, seconds)
        counter.switch(OFFLINE, now_ms)
        return counter


def local_day(at_ms: int, zone: ZoneInfo) -> date:
    return datetime.fromtimestamp(at_ms / 1000, zone).date()


def midnight_after(day: date, zone: ZoneInfo) -> int:
    """Epoch ms of the local midnight that ends `day`."""
    return round(datetime.combine(day + timedelta(days=1), wall_time(0), zone).timestamp() * 1000)


class UtilisationStore:
    """`<state_dir>/utilisation/<device>.json`; saves may come from a worker thread, the newest one wins."""

    def __init__(self, state_dir: Path, device_id: str) -> None:
        self.path = Path(state_dir) / "utilisation" / f"{quote(device_id, safe='')}.json"
        self._lock = threading.Lock()
        self._written = -1  # the sequence number of the data on disk

    def load(self) -> Any:
        """The saved document, or None when there is none (a first start)."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        return json.loads(text)

    def save(self, sequence: int, data: dict[str, Any]) -> None:
        """Write `data` unless a later sequence number is already on disk (a slow worker finishing late)."""
        encoded = json.dumps(data, sort_keys=True).encode()
        with self._lock:
            if sequence <= self._written:
                return
            write_atomically(self.path, encoded)
            self._written = sequence
