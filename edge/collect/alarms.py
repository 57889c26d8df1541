"""Alarms: the active list turned into raise/clear events, and the history ring read exactly once.

Active alarms are identified by (type, number, axis); a message text change is not a new alarm.

The CNC alarm history is a ring of up to 250 entries, read whole every history_interval. An entry is
identified by (occurrence time, alarm type, alarm number) — the CNC records times to the second, so
several different alarms may share a time, and we count identical keys so a repeat within the same
second is still seen. A persisted watermark (the newest occurrence time published, and which keys at
exactly that time were published) lets a reconnect or a daemon restart skip everything already
published, while a new alarm is published once. The watermark advances only after the caller has
published (`commit`), so a crash in between re-publishes rather than loses (at-least-once).

Limit: if someone sets the CNC clock back, alarms stamped before the watermark are not published.
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import quote

from edge.focas.model import ActiveAlarm, AlarmHistoryEntry
from edge.statefile import write_atomically

log = logging.getLogger(__name__)

AlarmKey = tuple[int, int, int]  # (type, number, axis)


@dataclass(frozen=True, slots=True)
class AlarmEvent:
    """An alarm that appeared ("raised") or went away ("cleared") between two status ticks."""

    kind: str  # "raised" | "cleared"
    alarm: ActiveAlarm
    timestamp_ms: int

    def as_dict(self) -> dict[str, object]:
        return {"event": self.kind, "type": self.alarm.type, "number": self.alarm.number,
                "axis": self.alarm.axis, "message": self.alarm.message, "timestamp_ms": self.timestamp_ms}


def alarm_key(alarm: ActiveAlarm) -> AlarmKey:
    return (alarm.type, alarm.number, alarm.axis)


class ActiveAlarmProjection:
    """The current active alarms of one machine; `update` returns what was raised and cleared.

    The state is kept across reconnects (an alarm still active after a reconnect is not raised again);
    `reset()` forgets it.
    """

    def __init__(self) -> None:
        self._active: dict[AlarmKey, ActiveAlarm] = {}
        self._status: int | None = None

    @property
    def active(self) -> list[ActiveAlarm]:
        return list(self._active.values())

    def status_changed(self, status_bits: int) -> bool:
        """Whether the alarm status word differs from the last one seen (read the messages then)."""
        changed = status_bits != self._status
        self._status = status_bits
        return changed

    def update(self, alarms: Iterable[ActiveAlarm], timestamp_ms: int) -> list[AlarmEvent]:
        current: dict[AlarmKey, ActiveAlarm] = {}
        for alarm in alarms:
            current.setdefault(alarm_key(alarm), alarm)
        events = [AlarmEvent("cleared", alarm, timestamp_ms)
                  for key, alarm in self._active.items() if key not in current]
        events += [AlarmEvent("raised", alarm, timestamp_ms)
                   for key, alarm in current.items() if key not in self._active]
        self._active = current
        return events

    def reset(self) -> None:
        self._active.clear()
        self._status = None


# ---- history ----------------------------------------------------------------------------------------------


def history_key(entry: AlarmHistoryEntry) -> str:
    """The dedup key (occurrence time, type, number) as a stable string."""
    return f"{_epoch_ms(entry.occurred)}:{entry.alm_type}:{entry.alm_no}"


def history_event(entry: AlarmHistoryEntry) -> dict[str, object]:
    return {"occurred": entry.occurred.astimezone(UTC).isoformat().replace("+00:00", "Z"),
            "occurred_ms": _epoch_ms(entry.occurred), "type": entry.alm_type, "number": entry.alm_no,
            "axis": entry.axis_no, "message": entry.message}


@dataclass(frozen=True, slots=True)
class Watermark:
    """Newest occurrence published (epoch ms) and how many of each key at exactly that time."""

    time_ms: int | None = None
    keys_at_time: tuple[tuple[str, int], ...] = ()

    def to_json(self) -> dict[str, object]:
        return {"version": 1, "time_ms": self.time_ms, "keys_at_time": dict(self.keys_at_time)}

    @classmethod
    def from_json(cls, data: object) -> Watermark:
        if not isinstance(data, dict) or data.get("version") != 1:
            raise ValueError(f"expected a version 1 watermark object, got {data!r:.80}")
        time_ms = data.get("time_ms")
        keys = data.get("keys_at_time", {})
        if time_ms is not None and not isinstance(time_ms, int):
            raise ValueError(f"time_ms must be an integer, got {time_ms!r}")
        if not isinstance(keys, dict) or not all(isinstance(v, int) for v in keys.values()):
            raise ValueError("keys_at_time must map keys to counts")
        return cls(time_ms, tuple(sorted((str(k), int(v)) for k, v in keys.items())))


class WatermarkStore:
    """One machine's watermark as a small JSON file, replaced atomically (temp, fsync, rename)."""

    def __init__(self, state_dir: Path, machine_id: str) -> None:
        self.path = Path(state_dir) / "alarm-history" / f"{quote(machine_id, safe='')}.json"

    def load(self) -> Watermark:
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return Watermark()
        try:
            return Watermark.from_json(json.loads(text))
        except ValueError as exc:
            log.warning("alarm history watermark unreadable, starting fresh path=%s error=%s", self.path, exc)
            return Watermark()

    def save(self, watermark: Watermark) -> None:
        write_atomically(self.path, json.dumps(watermark.to_json(), sort_keys=True).encode())


class AlarmHistoryDedup:
    """Which history entries are new; `commit` advances and persists the watermark after publishing."""

    def __init__(self, store: WatermarkStore | None = None) -> None:
        self.store = store
        self.watermark = store.load() if store is not None else Watermark()

    def new_entries(self, entries: Sequence[AlarmHistoryEntry]) -> list[AlarmHistoryEntry]:
        """Entries not yet published, oldest first (equal times keep the ring's order, oldest first)."""
        ordered = sorted(reversed(entries), key=lambda e: _epoch_ms(e.occurred))  # ring is newest first
        mark = self.watermark
        if mark.time_ms is None:
            return ordered
        already = Counter(dict(mark.keys_at_time))
        fresh = []
        for entry in ordered:
            when = _epoch_ms(entry.occurred)
            if when < mark.time_ms:
                continue
            if when == mark.time_ms:
                key = history_key(entry)
                if already[key] > 0:
                    already[key] -= 1
                    continue
            fresh.append(entry)
        return fresh

    def commit(self, published: Sequence[AlarmHistoryEntry]) -> None:
        """Record `published` (the result of new_entries, once published) and persist the watermark."""
        if not published:
            return
        newest = max(_epoch_ms(e.occurred) for e in published)
        counts: Counter[str] = Counter()
        if self.watermark.time_ms == newest:
            counts.update(dict(self.watermark.keys_at_time))
        counts.update(history_key(e) for e in published if _epoch_ms(e.occurred) == newest)
        if self.watermark.time_ms is not None and newest < self.watermark.time_ms:
            return
        self.watermark = Watermark(newest, tuple(sorted(counts.items())))
        if self.store is not None:
            self.store.save(self.watermark)


def _epoch_ms(when: datetime) -> int:
    aware = when if when.tzinfo is not None else when.replace(tzinfo=UTC)
    return round(aware.timestamp() * 1000)
