"""The Sparkplug B edge-node session, sans-IO: state in, MQTT messages (topic, bytes) out.

One object per daemon owns everything a host checks: seq (one counter for all node and device messages,
assigned as each message is built, and the caller publishes in build order, so seq order is wire order),
births from the last known values, alias-only DATA, DDEATH/NDEATH, the rebirth hold and command parsing.
No sockets, no asyncio and no clock reads beyond the injected `clock`, so every rule is unit-testable.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import attrgetter, itemgetter
from typing import Any

from edge.publish import birth_bytes
from edge.publish import ddata as dd
from edge.publish import payload as pl
from edge.publish.aliases import NODE, AliasMap
from edge.publish.device_table import DeviceTable, MetricLayout, layout_of
from edge.publish.node_commands import (
    NAMESPACE,
    CommandEvent,
    CommandReader,
)
from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.samples import MetricSpec, MetricType, Quality, Sample

log = logging.getLogger(__name__)

_FORBIDDEN_ID_CHARS = frozenset("+/#")
_by_timestamp = attrgetter("timestamp_ms")
_row_name = itemgetter(0)
_row_timestamp = itemgetter(3)


def now_ms() -> int:
    return time.time_ns() // 1_000_000


def check_id(kind: str, value: str) -> str:
    """Sparkplug ids are non-empty UTF-8 without + / # (they are topic levels)."""
    if not value or _FORBIDDEN_ID_CHARS.intersection(value):
        raise ValueError(f"{kind} {value!r}: expected a non-empty string without '+', '/' or '#'")
    return value


@dataclass(frozen=True, slots=True)
class Outgoing:
    """One MQTT message to publish, in the order given."""

    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False


def _data_message_builder() -> Callable[[str, bytes], Outgoing]:
    """`data_message(topic, payload)`: the `Outgoing(topic, payload)` of a DATA message (QoS 0, not retained),
    built by setting its slots: a frozen dataclass's __init__ goes through object.__setattr__ (0.5 us), and
    every tick of every machine with a change publishes one (0.28 us this way)."""
    new = object.__new__
    set_topic, set_payload, set_qos, set_retain = (getattr(Outgoing, name).__set__
                                                   for name in ("topic", "payload", "qos", "retain"))

    def data_message(topic: str, payload: bytes) -> Outgoing:
        message = new(Outgoing)
        set_topic(message, topic)
        set_payload(message, payload)
        set_qos(message, 0)
        set_retain(message, False)
        return message

    return data_message


data_message = _data_message_builder()


@dataclass(frozen=True, slots=True)
class ReleasedEvents:
    """A batch of events a rebirth held, released after its device's DBIRTH: the samples and the DDATA that
    carries them, from one list, so what is sent and what the replay dedupe records as sent are the same."""

    device_id: str
    samples: Sequence[Sample]
    message: Outgoing


class SparkplugNode:
    """Births, data, deaths and commands for one edge node and its devices."""

    def __init__(self, group_id: str, edge_node_id: str, aliases: AliasMap,
                 clock: Callable[[], int] = now_ms) -> None:
        self.group_id = check_id("group id", group_id)
        self.edge_node_id = check_id("edge node id", edge_node_id)
        self._aliases = aliases
        self._clock = clock
        self._seq = 0
        self._bdseq: int | None = None
        self.born = False  # an NBIRTH went out in the current MQTT session
        self.holding = False  # a rebirth is pending: DATA stops until the births are re-sent
        # Counts NBIRTHs: a device is born (its DATA may go out) when its DBIRTH went out after the latest
        # one (DeviceTable.born_in), so the DBIRTHs after an NBIRTH can go out over several loop turns.
        self.generation = 0
        self._held_events: list[tuple[str, list[Sample]]] = []
        self._node = DeviceTable(layout_of(()), (), online=True)  # NDATA goes to _ndata_topic
        self._devices: dict[str, DeviceTable] = {}
        self.unknown_metrics = 0
        self.encode_errors = 0
        self._warned: set[tuple[str, str]] = set()
        base = f"{NAMESPACE}/{group_id}"
        self.ncmd_topic = f"{base}/NCMD/{edge_node_id}"
        self.dcmd_topic_filter = f"{base}/DCMD/{edge_node_id}/+"
        self.ndeath_topic = f"{base}/NDEATH/{edge_node_id}"
        self.nbirth_topic = f"{base}/NBIRTH/{edge_node_id}"
        self._ndata_topic = f"{base}/NDATA/{edge_node_id}"
        self._device_topic = f"{base}/{{kind}}/{edge_node_id}/{{device}}"
        self._commands = CommandReader(group_id, edge_node_id, aliases, lambda: self._node, self._devices)

    # -- session -------------------------------------------------------------------------------------

    @property
    def live(self) -> bool:
        """DATA may be published now: born in this session and no rebirth pending."""
        return self.born and not self.holding

    @property
    def bdseq(self) -> int | None:
        return self._bdseq

    def will(self, bdseq: int) -> Outgoing:
        """The NDEATH registered as Will: QoS 1, not retained, only bdSeq (Int64), no seq."""
        return Outgoing(self.ndeath_topic, pl.bdseq_payload(bdseq, self._clock()), qos=1, retain=False)

    def session_started(self, bdseq: int) -> None:
        """A CONNECT carrying `bdseq` was accepted; nothing is born in the new session yet."""
        self._bdseq = bdseq
        self.born = False
        self.holding = False
        self._held_events.clear()

    def session_lost(self) -> None:
        self.born = False
        self.holding = False
        self._held_events.clear()

    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) & 0xFF
        return seq

    def births(self) -> list[Outgoing]:
        """NBIRTH (seq 0, same bdSeq) then a DBIRTH per online device, then any events held by a rebirth."""
        out = [self.nbirth()]
        for device_id in self.unborn_devices():
            out.extend(self.dbirth(device_id))
        out.extend(released.message for released in self.release_held_events())
        return out

    def nbirth(self) -> Outgoing:
        """The NBIRTH (seq 0, same bdSeq): the node is live from here, each device from its `dbirth`
        (`births` is this, every DBIRTH and `release_held_events`, at once)."""
        if self._bdseq is None:
            raise RuntimeError("births requested before session_started(bdseq)")
        self._seq = 0
        ts = self._clock()
        p = Payload(timestamp=ts, seq=self._next_seq())
        p.metrics.add(name=pl.BDSEQ_METRIC, datatype=DataType.Int64, timestamp=ts, long_value=self._bdseq)
        p.metrics.add(name=pl.REBIRTH_METRIC, datatype=DataType.Boolean, timestamp=ts, boolean_value=False)
        self._add_birth_metrics(p, NODE, self._node, ts)
        out = Outgoing(self.nbirth_topic, p.SerializeToString())
        self.born = True
        self.holding = False
        self.generation += 1
        return out

    def unborn_devices(self) -> list[str]:
        """The online devices whose DBIRTH has not gone out since the latest NBIRTH."""
        generation = self.generation
        return [d for d, dev in self._devices.items() if dev.online and dev.born_in != generation]

    def dbirth(self, device_id: str) -> list[Outgoing]:
        """The device's DBIRTH, if the node is live and the device online and not born since the NBIRTH."""
        dev = self._devices.get(device_id)
        if dev is None or not (self.live and dev.online) or dev.born_in == self.generation:
            return []
        return [self._dbirth(device_id, dev)]

    def release_held_events(self, device_id: str | None = None) -> list[ReleasedEvents]:
        """The events a rebirth held (all, or one device's), taken: each batch with the DDATA built from it,
        for the devices live now (born since the NBIRTH); the rest are dropped (their device went offline)."""
        if device_id is None:
            held, self._held_events = self._held_events, []
        else:
            held = [pair for pair in self._held_events if pair[0] == device_id]
            if not held:
                return []
            self._held_events = [pair for pair in self._held_events if pair[0] != device_id]
        released: list[ReleasedEvents] = []
        for held_id, events in held:
            dev = self._devices.get(held_id)
            if dev is None or not self.is_live(held_id):
                continue
            known = self._known(held_id, dev, events)  # the device may have been declared again meanwhile
            if known:
                released.append(ReleasedEvents(held_id, known, self._data(dev.data_topic, dev, known)))
        return released

    def birth_record(self, device_id: str) -> tuple[dict[str, Any], tuple[Sample | None, ...]] | None:
        """What the device's DBIRTH carries, compactly: its layout's slots (shared by the devices declared
        alike) and its last samples by position; None for a device that is not online."""
        dev = self._devices.get(device_id)
        return (dev.layout.slots, tuple(dev.last)) if dev is not None and dev.online else None

    def _add_birth_metrics(self, p: Payload, device_key: str, dev: DeviceTable, ts: int) -> None:
        """The birth's metrics with the protobuf runtime (the NBIRTH; DBIRTHs: edge.publish.birth_bytes)."""
        for spec, sample in zip(dev.layout.specs.values(), dev.last, strict=True):
            self._add_birth_metric(p, device_key, spec, sample, ts)
        dev.not_good = {s.name for s in dev.last if s is not None and s.quality is not Quality.GOOD}

    def _add_birth_metric(self, p: Payload, device_key: str, spec: MetricSpec, sample: Sample | None,
                          ts: int) -> None:
        alias = self._aliases.alias(device_key, spec.name)  # assigned when the device was declared
        name = spec.name
        value = None if sample is None else sample.value
        quality = Quality.GOOD if sample is None else sample.quality
        try:
            m = pl.add_birth_metric(p.metrics, name, alias, spec.type, value,
                                    ts if sample is None else sample.timestamp_ms, unit=spec.unit,
                                    quality=quality, description=spec.description)
        except (TypeError, ValueError, OverflowError) as exc:  # Overflow: float() of a huge int
            self._encode_failed(name, exc)
            del p.metrics[-1]
            pl.add_birth_metric(p.metrics, name, alias, spec.type, None, ts,
                                unit=spec.unit, quality=Quality.BAD, description=spec.description)
            return
        if sample is not None and sample.historical:
            m.is_historical = True

    def _dbirth(self, device_id: str, dev: DeviceTable) -> Outgoing:
        ts = self._clock()
        seq = self._next_seq()
        specs = list(dev.layout.specs.values())

        def runtime(position: int, at: int) -> bytes:  # one metric the byte writer leaves to protobuf
            scratch = Payload()
            self._add_birth_metric(scratch, device_id, specs[position], dev.last[position], at)
            return scratch.SerializeToString()

        payload = birth_bytes.birth_payload(ts, seq, birth_bytes.birth_metrics(dev, ts, runtime))
        dev.not_good = {s.name for s in dev.last if s is not None and s.quality is not Quality.GOOD}
        dev.born_in = self.generation
        return Outgoing(self._device_topic.format(kind="DBIRTH", device=device_id), payload)

    def request_rebirth(self) -> bool:
        """Stop DATA at once (until births()); False if there is nothing born to rebirth."""
        if not self.born:
            return False
        self.holding = True
        return True

    def ndeath(self) -> Outgoing:
        """An explicit NDEATH before an intentional DISCONNECT (same bdSeq as the Will)."""
        if self._bdseq is None:
            raise RuntimeError("ndeath requested before session_started(bdseq)")
        return self.will(self._bdseq)

    def shutdown(self) -> list[Outgoing]:
        """Clean shutdown: DDEATH for every online device, then NDEATH. Devices stay registered."""
        out: list[Outgoing] = []
        if self.born:
            for device_id, dev in self._devices.items():
                if dev.online and dev.born_in == self.generation:
                    out.append(self._ddeath(device_id))
        if self._bdseq is not None:
            out.append(self.ndeath())
        self.born = False
        return out

    # -- node metrics --------------------------------------------------------------------------------

    def set_node_metrics(self, samples: Sequence[Sample]) -> list[Outgoing]:
        """Record gateway metrics; NDATA for changed ones, or a full rebirth when a new metric appears."""
        node = self._node
        new = [s for s in samples if s.name not in node.layout.slots]
        if new:
            added: dict[str, MetricSpec] = {}
            for s in new:
                added[check_metric_name(s.name)] = MetricSpec(s.name, s.type)
            node = self._node = self._grown(NODE, node, node.layout.extended(list(added.values())))
            self._aliases.save()
        changed = [s for s in samples if (old := node.last_of(s.name)) is None or old.value != s.value
                   or old.quality is not s.quality]
        node.record(samples)
        if not self.live:
            return []
        if new:
            return self.births()
        if not changed:
            return []
        return [self._data(self._ndata_topic, node, changed)]

    # -- devices -------------------------------------------------------------------------------------

    def device_online(self, device_id: str, specs: Sequence[MetricSpec],
                      samples: Sequence[Sample]) -> list[Outgoing]:
        """Declare a device with every metric it will report; DBIRTH now if the node is born."""
        check_id("device id", device_id)
        for spec in specs:
            check_metric_name(spec.name)
        old = self._devices.get(device_id)
        dev = self._grown(device_id, old, layout_of(specs))
        dev.online, dev.not_good = True, set()
        dev.data_topic = self._device_topic.format(kind="DDATA", device=device_id)
        self._aliases.save()
        slots = dev.layout.slots
        dev.record([s for s in samples if s.name in slots])
        self._devices[device_id] = dev
        if not self.live:
            return []
        return [self._dbirth(device_id, dev)]

    def device_data(self, device_id: str, samples: Sequence[Sample]) -> list[Outgoing]:
        """Record new values; DDATA (alias only, metric timestamp = the CNC's) when live and online."""
        dev = self._devices.get(device_id)
        if dev is None:
            self._unknown(device_id, "<device>")
            return []
        try:  # the common tick: every name declared, so no separate check of them (_known) first
            dev.record(samples)
            known = samples
        except KeyError:  # an undeclared name: the declared ones recorded (again, in order), the rest counted
            known = self._known(device_id, dev, samples)
            dev.record(known)
        if not (self.live and dev.online and dev.born_in == self.generation) or not known:
            return []
        return [self._data(dev.data_topic, dev, known)]

    def device_events(self, device_id: str, events: Sequence[Sample]) -> list[Outgoing]:
        """Events (alarm raise/clear, history) as DDATA with their own occurrence time; held in a rebirth."""
        dev = self._devices.get(device_id)
        if dev is None:
            self._unknown(device_id, "<device>")
            return []
        known = self._known(device_id, dev, events)
        if not known:
            return []
        if self.holding:
            self._held_events.append((device_id, list(known)))
            return []
        if not (self.live and dev.online and dev.born_in == self.generation):
            return []
        return [self._data(dev.data_topic, dev, known)]

    def historical_data(self, device_id: str, samples: Sequence[Sample]) -> list[Outgoing]:
        """Replayed store-and-forward samples: DDATA with is_historical=true and their own timestamps.

        Only while live and the device is born; the device's current values (births) are not touched.
        Metrics no longer in the DBIRTH are counted as unknown and left out.
        """
        return self.historical_rows(device_id, [[s.name, s.value, None, s.timestamp_ms, s.quality]
                                                for s in samples])

    def historical_rows(self, device_id: str, rows: Sequence[Sequence[Any]]) -> list[Outgoing]:
        """historical_data for the spool's parsed rows [name, value, type, timestamp_ms, quality]
        (edge.publish.spool_rows), encoded without building a Sample each (a 1,000-machine backlog is
        ~150,000 values a second to replay). TypeError, ValueError or KeyError for a row that is not one
        (a corrupt spool), with no seq taken."""
        dev = self._devices.get(device_id)
        if dev is None or not (self.live and dev.online and dev.born_in == self.generation):
            return []
        specs = dev.layout.slots
        if not all(map(specs.__contains__, map(_row_name, rows))):
            for row in rows:
                if row[0] not in specs:
                    self._unknown(device_id, row[0])
            rows = [row for row in rows if row[0] in specs]
        if not rows:
            return []
        return [self._historical(dev, rows)]

    def device_offline(self, device_id: str) -> list[Outgoing]:
        """DDEATH (with seq) if the device was born in this session; it keeps its aliases and values."""
        dev = self._devices.get(device_id)
        if dev is None or not dev.online:
            return []
        dev.online = False
        if not self.born or dev.born_in != self.generation:
            return []  # no DBIRTH since the NBIRTH (the births are still going out): nothing to end
        return [self._ddeath(device_id)]

    def is_online(self, device_id: str) -> bool:
        dev = self._devices.get(device_id)
        return dev is not None and dev.online

    def is_live(self, device_id: str) -> bool:
        """The device's DATA may go out now: the node live, the device online and born since the NBIRTH."""
        dev = self._devices.get(device_id)
        return self.live and dev is not None and dev.online and dev.born_in == self.generation

    def device_ids(self) -> list[str]:
        return list(self._devices)

    def _grown(self, device_key: str, old: DeviceTable | None, layout: MetricLayout) -> DeviceTable:
        """A table for `layout` (aliases assigned to its new names), keeping `old`'s last values and state."""
        table = DeviceTable(layout, self._aliases.aliases(device_key, layout.names))
        if old is not None:
            table.record([s for s in old.last_samples() if s.name in layout.slots])
            table.online, table.not_good, table.data_topic = old.online, old.not_good, old.data_topic
            table.born_in = old.born_in
        return table

    def _ddeath(self, device_id: str) -> Outgoing:
        ts = self._clock()
        p = Payload(timestamp=ts, seq=self._next_seq())
        return Outgoing(self._device_topic.format(kind="DDEATH", device=device_id), p.SerializeToString())

    def _known(self, device_id: str, dev: DeviceTable, samples: Sequence[Sample]) -> Sequence[Sample]:
        specs = dev.layout.slots
        for s in samples:  # a plain loop: faster than all(map(...)) for a tick's handful of values
            if s.name not in specs:
                break
        else:
            return samples
        known = []
        for s in samples:
            if s.name in specs:
                known.append(s)
            else:
                self._unknown(device_id, s.name)
        return known

    def _unknown(self, device_id: str, name: str) -> None:
        self.unknown_metrics += 1
        if (device_id, name) not in self._warned:
            self._warned.add((device_id, name))
            log.warning("metric not declared in the birth, not published device=%s metric=%s",
                        device_id or "<node>", name)

    def _encode_failed(self, name: str, exc: Exception) -> None:
        self.encode_errors += 1
        log.warning("metric value cannot be encoded metric=%s error=%s", name, exc)

    def _data(self, topic: str, dev: DeviceTable, samples: Sequence[Sample]) -> Outgoing:
        """One DATA message: metrics in chronological order, alias + timestamp + value (+ Quality).

        Written straight to bytes (edge.publish.ddata). The loop's first branch is the common metric (a
        GOOD value that was GOOD last time, not historical); the rest goes through `_metric`. Replayed
        samples have their own loop (`_historical`).
        """
        parts = [dd.payload_head(self._clock())]
        tail = dd.payload_tail(self._next_seq())
        append = parts.append
        headers = dd.SHORT_RECORD_HEADERS
        double, double_field = dd.DOUBLE_FIELD, dd.VALUE_FIELDS[MetricType.DOUBLE]
        slots, alias_data, alias_ends = dev.layout.slots, dev.alias_data, dev.alias_ends
        not_good = dev.not_good
        good = Quality.GOOD
        last_ts = -1
        stamp = b""
        double_size = 0
        for s in sorted(samples, key=_by_timestamp):
            position, value_field, mtype = slots[s.name]
            alias = alias_data[alias_ends[position]:alias_ends[position + 1]]
            if s.timestamp_ms != last_ts:  # sorted: equal timestamps are adjacent
                last_ts = s.timestamp_ms
                stamp = dd.timestamp_field(last_ts)
                double_size = len(stamp) + 9  # a double metric's body, but for its alias field
            value = s.value
            if s.quality is good and not s.historical and (not not_good or s.name not in not_good):
                if value_field is double_field and type(value) is float:  # most values: no concatenation
                    parts += (headers[len(alias) + double_size], alias, stamp, double(0x69, value))
                    continue
                if value is not None and (data := value_field(value)) is not None:
                    body = alias + stamp + data
                else:
                    append(self._metric(s, alias + stamp, value_field, mtype, not_good))
                    continue
                try:
                    append(headers[len(body)] + body)
                except IndexError:  # a body of 128 bytes or more: a longer length varint
                    append(dd.metric_record(body))
                continue
            append(self._metric(s, alias + stamp, value_field, mtype, not_good))
        append(tail)
        return data_message(topic, b"".join(parts))

    def _historical(self, dev: DeviceTable, rows: Sequence[Sequence[Any]]) -> Outgoing:
        """One DATA message of replayed rows, every metric is_historical, in chronological order.

        A GOOD value whose metric was GOOD when last published live is alias + timestamp + is_historical +
        value: a float of a Double metric (most values) as its parts, no concatenation and no value writer
        called (as `_data`); the rest goes through `_metric` (as a Sample), on a copy of the live quality
        bookkeeping (a replay leaves it alone)."""
        parts = [dd.payload_head(self._clock())]
        append = parts.append
        headers = dd.SHORT_RECORD_HEADERS
        historical = dd.HISTORICAL
        double, double_field = dd.DOUBLE_FIELD, dd.VALUE_FIELDS[MetricType.DOUBLE]
        slots, alias_data, alias_ends = dev.layout.slots, dev.alias_data, dev.alias_ends
        not_good = set(dev.not_good) if dev.not_good else None  # copied only when a replay may change it
        good = int(Quality.GOOD)
        last_ts = -1
        stamp = b""
        double_size = 0
        for name, value, _, ts, quality in sorted(rows, key=_row_timestamp):
            position, value_field, mtype = slots[name]
            alias = alias_data[alias_ends[position]:alias_ends[position + 1]]
            if ts != last_ts:
                last_ts = ts
                stamp = dd.timestamp_field(ts) + historical
                double_size = len(stamp) + 9  # a double metric's body, but for its alias field
            if quality == good and (not_good is None or name not in not_good):
                if value_field is double_field and type(value) is float:
                    parts += (headers[len(alias) + double_size], alias, stamp, double(0x69, value))
                    continue
                if value is not None and (data := value_field(value)) is not None:
                    body = alias + stamp + data
                    try:
                        append(headers[len(body)] + body)
                    except IndexError:  # a body of 128 bytes or more: a longer length varint
                        append(dd.metric_record(body))
                    continue
            if not_good is None:
                not_good = set()
            sample = Sample(name, value, mtype, ts, Quality(quality), True)
            append(self._metric(sample, alias + stamp[:-len(historical)], value_field, mtype, not_good))
        append(dd.payload_tail(self._next_seq()))  # last: a row that raises above takes no seq
        return Outgoing(dev.data_topic, b"".join(parts))

    def _metric(self, s: Sample, head: bytes, value_field: dd.ValueField, mtype: MetricType,
                not_good: set[str]) -> bytes:
        """One metric record the general way: null, historical, Quality, runtime-encoded values, errors."""
        name = s.name
        value = s.value
        flags = dd.HISTORICAL if s.historical else b""
        if value is None:
            flags += dd.NULL
            data = b""
        else:
            fast = value_field(value)
            if fast is not None:
                data = fast
            else:
                try:
                    data = dd.runtime_value_field(mtype, value)
                except (TypeError, ValueError, OverflowError) as exc:
                    self._encode_failed(name, exc)
                    not_good.add(name)
                    return dd.metric_record(head + dd.NULL + dd.QUALITY_FIELD[Quality.BAD])
        if s.quality is not Quality.GOOD:
            flags += dd.QUALITY_FIELD[s.quality]
            not_good.add(name)
        elif name in not_good:
            flags += dd.QUALITY_FIELD[Quality.GOOD]  # tell the host the value is good again
            not_good.discard(name)
        return dd.metric_record(head + flags + data)

    # -- commands ------------------------------------------------------------------------------------

    def parse_command(self, topic: str, data: bytes) -> list[CommandEvent]:
        """NCMD/DCMD -> events; anything unusable becomes CommandIgnored with the reason."""
        return self._commands.parse(topic, data)


def check_metric_name(name: str) -> str:
    if not name or name.startswith("/") or name.endswith("/") or "//" in name:
        raise ValueError(f"metric name {name!r}: expected non-empty '/'-separated folders and a leaf name")
    return name
