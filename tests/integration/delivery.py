"""Drill bookkeeping: what the collector handed the publisher vs what a subscriber received.

A consumer's dedup key for a value is (machine, metric name, CNC timestamp); for alarm events the event
body (number, type, raise/clear, occurrence) is part of it, since two events can share a tick.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections import defaultdict
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from edge.publish.publisher import Publisher
from edge.samples import Sample
from edge.sim.fleet import Fleet, MachineSpec
from tests.integration.mqtt_observer import Received

Key = tuple[Any, ...]
EVENT_NAMES = ("Alarm/Event", "Alarm/History")


def key_of(device: str, name: str, ts: int, value: object) -> Key:
    if name in EVENT_NAMES:
        return (device, name, ts, value if isinstance(value, str) else json.dumps(value, sort_keys=True))
    return (device, name, ts)


@dataclass
class Collected:
    """Every sample the pollers gave the publisher (data and events), with the phase it was collected in."""

    keys: dict[Key, str] = field(default_factory=dict)
    birth_keys: set[Key] = field(default_factory=set)  # full-state values: may arrive, need not
    phase: str = "up"
    per_device: dict[str, int] = field(default_factory=lambda: defaultdict(int))

    def spy_on(self, publisher: Publisher) -> None:
        data, send_events, online = publisher.device_data, publisher.device_events, publisher.device_online

        async def device_online(device_id: str, specs: Sequence[Any], samples: Sequence[Sample]) -> None:
            self.birth_keys.update(key_of(device_id, s.name, s.timestamp_ms, s.value) for s in samples)
            await online(device_id, specs, samples)

        async def device_data(device_id: str, samples: Sequence[Sample]) -> None:
            self._record(device_id, samples)
            await data(device_id, samples)

        async def device_events(device_id: str, events: Sequence[Sample]) -> None:
            self._record(device_id, events)
            await send_events(device_id, events)

        publisher.device_online = device_online  # type: ignore[method-assign]
        publisher.device_data = device_data  # type: ignore[method-assign]
        publisher.device_events = device_events  # type: ignore[method-assign]

    def _record(self, device_id: str, samples: Sequence[Sample]) -> None:
        for s in samples:
            self.keys.setdefault(key_of(device_id, s.name, s.timestamp_ms, s.value), self.phase)
            self.per_device[f"{device_id}:{self.phase}"] += 1


@dataclass
class Arrival:
    key: Key
    historical: bool
    received_s: float
    birth: bool = False  # a DBIRTH metric: the value as the host's current state (a historian stores it)


def sparkplug_arrivals(messages: Sequence[Received], group: str, node: str) -> list[Arrival]:
    """Every DDATA metric, and every DBIRTH metric with a value, as (device, name, ts) using the aliases of
    the DBIRTHs seen. A value a birth carried has reached the host: its replay would be a duplicate."""
    aliases: dict[str, dict[int, str]] = defaultdict(dict)
    out: list[Arrival] = []
    for m in messages:
        parts = m.topic.split("/")
        if len(parts) != 5 or parts[1] != group or parts[3] != node:
            continue
        device = parts[4]
        if parts[2] == "DBIRTH":
            for metric in m.spb().metrics:
                aliases[device][metric.alias] = metric.name
                if not metric.is_null:
                    value = metric.string_value if metric.WhichOneof("value") == "string_value" else None
                    out.append(Arrival(key_of(device, metric.name, metric.timestamp, value), metric.is_historical,
                                       0.0, birth=True))
        elif parts[2] == "DDATA":
            for metric in m.spb().metrics:
                name = aliases[device][metric.alias]
                value = metric.string_value if metric.WhichOneof("value") == "string_value" else None
                out.append(Arrival(key_of(device, name, metric.timestamp, value), metric.is_historical, 0.0))
    return out


def json_arrivals(messages: Sequence[Received], prefix: str) -> list[Arrival]:
    """Every JSON value/event document as (device, name, ts)."""
    out: list[Arrival] = []
    for m in messages:
        parts = m.topic.split("/", 3)
        if len(parts) < 3 or parts[0] != prefix or m.retain:
            continue
        device, kind = parts[1], parts[2]
        if kind not in ("state", "history", "events"):
            continue
        doc = json.loads(m.payload)
        name = doc.get("name") or parts[3]
        out.append(Arrival(key_of(device, name, int(doc["ts"]), doc["value"]), bool(doc.get("historical")),
                           0.0))
    return out


@dataclass
class Verdict:
    missing: list[Key]
    unexpected: list[Key]
    duplicates: int
    out_of_order: list[str]
    not_flagged: list[Key]
    historical: int

    def problems(self) -> list[str]:
        out = []
        if self.missing:
            out.append(f"{len(self.missing)} collected samples never arrived, e.g. {self.missing[:3]}")
        if self.unexpected:
            out.append(f"{len(self.unexpected)} arrived but were never collected, e.g. {self.unexpected[:3]}")
        if self.out_of_order:
            out.append(f"out of CNC-time order: {self.out_of_order[:3]}")
        if self.not_flagged:
            out.append(f"{len(self.not_flagged)} collected while down never arrived as historical, "
                       f"e.g. {self.not_flagged[:3]}")
        return out


def compare(collected: Collected, arrivals: Sequence[Arrival], down_phases: tuple[str, ...] = ("down",)) -> Verdict:
    """Exactly once after dedup, per-metric CNC-time order within the live and the historical stream."""
    seen: dict[Key, Arrival] = {}
    duplicates = 0
    last: dict[tuple[Any, ...], int] = {}
    out_of_order: list[str] = []
    as_historical: set[Key] = set()
    for a in arrivals:
        if a.historical or a.birth:  # held, then carried by a birth: the host has it, with its timestamp
            as_historical.add(a.key)
        if a.key in seen:
            duplicates += 1
            continue
        seen[a.key] = a
        stream = (a.key[0], a.key[1], a.historical)
        if a.key[1] not in EVENT_NAMES and not a.birth:
            ts = a.key[2]
            if stream in last and ts < last[stream]:
                out_of_order.append(f"{stream}: {ts} after {last[stream]}")
            last[stream] = max(ts, last.get(stream, ts))
    missing = [k for k in collected.keys if k not in seen]
    unexpected = [k for k in seen if k not in collected.keys and k not in collected.birth_keys]
    not_flagged = [k for k, phase in collected.keys.items() if phase in down_phases and k not in as_historical]
    return Verdict(missing, unexpected, duplicates, out_of_order, not_flagged,
                   sum(1 for a in seen.values() if a.historical))


def now() -> float:
    return time.monotonic()


@contextlib.asynccontextmanager
async def changing_fleet(machines: int) -> AsyncIterator[Fleet]:
    """Simulated 30i machines whose Macro/500 changes every 50 ms: every tick of 0.1 s or more has deltas."""
    async with Fleet([MachineSpec(profile="30i") for _ in range(machines)], base_port=0) as fleet:
        changer = asyncio.create_task(keep_changing(list(fleet)))
        try:
            yield fleet
        finally:
            changer.cancel()


async def keep_changing(machines: Sequence[Any], period_s: float = 0.05, macro: int = 500) -> None:
    """Write a new value to one macro of every machine each `period_s` (cancel to stop), so every poll
    tick has a delta to publish."""
    value = 0.0
    while True:
        value += 1.0
        for m in machines:
            m.state.write_macro(macro, value, protocol="scenario")
        await asyncio.sleep(period_s)
