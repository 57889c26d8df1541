"""The measuring subscriber: receipt times of Sparkplug messages, change-to-broker latency, node counters.

Runs paho's network loop in a thread of the benchmark process (not the gateway's). While messages arrive it
only notes each DDATA's and DBIRTH's receipt time and raw payload; the payloads are decoded when the figures
are taken, after the measuring window, so the subscriber does not take CPU from the gateway it measures
(at 1,000 messages a second on two cores it would). Node messages (NBIRTH, NDATA: the overrun counter) are
rare and decoded as they come. For each DDATA it
notes the receipt time; the stamp macro's value is the simulator's wall-clock time of the change, so
receipt minus value is change-to-broker latency (both clocks are this host's). The first metric's
timestamp (the CNC time the gateway stamped the tick with, less that CNC clock's offset from this host's:
`cnc_offset`, 0 unless the fleet's clocks are spread) gives read-to-broker latency.
The clock macro's value is the simulator's clock when it answered the tick's request, so its timestamp
minus its value is the stamp's error.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from bench.simproc import stamp_latency
from edge.publish.sparkplug_b_pb2 import Payload
from edge.sim.state_clock import clock_macro_error

OVERRUNS_METRIC = "Gateway/PollOverruns"


class LatencySubscriber:
    """Subscribes to one Sparkplug group; `recording` decides whether latencies are kept."""

    def __init__(self, host: str, port: int, group: str, stamp_metric: str, clock_metric: str = "",
                 track_seq: bool = False, cnc_offset: Callable[[str], float] | None = None) -> None:
        self.group = group
        self.cnc_offset = cnc_offset  # device -> seconds its CNC clock runs ahead of this host's
        self.track_seq = track_seq  # check the node's seq on every message (costs a decode per message)
        self.seq_gaps: list[tuple[int, int]] = []  # (expected, got) where a message of the node went missing
        self._last_seq: int | None = None
        self.stamp_metric = stamp_metric
        self.clock_metric = clock_metric
        self.recording = False
        self.change_latency_s: list[float] = []
        self.sample_latency_s: list[float] = []
        self.stamp_error_s: list[float] = []
        # `sample` split where the gateway encodes the message (the payload timestamp): CNC stamp -> encoded
        # (the CNC's answer in transit and queued in the gateway), encoded -> received (broker, subscriber).
        self.in_gateway_s: list[float] = []
        self.to_subscriber_s: list[float] = []
        self.births: set[str] = set()
        self.birth_times: dict[str, float] = {}  # device -> receipt of its first DBIRTH
        self.dbirths = Counter[str]()  # every DBIRTH per device: a second one is a rebirth
        self.deaths = 0
        self.ddata = Counter[str]()
        self.values = 0  # metrics in the DDATA recorded (values published)
        self.messages = 0
        self.overruns: int | None = None
        self._stamp_alias: dict[str, int] = {}
        self._clock_alias: dict[str, int] = {}
        self._node_aliases: dict[int, str] = {}
        # (receipt, kind, device, payload) of DBIRTHs and recorded DDATAs, in order, not yet decoded
        self._pending: list[tuple[float, str, str, bytes]] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-subscriber-{id(self)}")
        self.client.on_connect = lambda c, *a: c.subscribe(f"spBv1.0/{group}/#", qos=0)
        self.client.on_subscribe = lambda *a: self._subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect(host, port, keepalive=30)
        self.client.loop_start()
        if not self._subscribed.wait(10):
            self.close()
            raise RuntimeError(f"subscriber could not subscribe on {host}:{port}")

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()

    def _on_message(self, client: paho.Client, userdata: Any, message: paho.MQTTMessage) -> None:
        received = time.time()
        parts = message.topic.split("/")
        if len(parts) < 4:
            return
        kind = parts[2]
        data = bytes(message.payload)
        if self.track_seq and kind != "NDEATH":
            self._check_seq(kind, Payload.FromString(data).seq)
        if kind == "DDATA":
            self._ddata(parts[4], data, received)
        elif kind == "DBIRTH":
            self._dbirth(parts[4], data)
        elif kind in ("NBIRTH", "NDATA"):
            self._node(kind, data)
        elif kind == "DDEATH":
            self.deaths += 1

    def _check_seq(self, kind: str, seq: int) -> None:
        """Sparkplug's node-wide seq: each message of the node is the last one's + 1 (mod 256); NBIRTH is 0."""
        if kind != "NBIRTH" and self._last_seq is not None and seq != (self._last_seq + 1) % 256:
            with self._lock:
                self.seq_gaps.append(((self._last_seq + 1) % 256, seq))
        self._last_seq = seq

    def _ddata(self, device: str, data: bytes, received: float) -> None:
        self.ddata[device] += 1
        if self.recording:
            with self._lock:
                self._pending.append((received, "DDATA", device, data))

    def _dbirth(self, device: str, data: bytes) -> None:
        received = time.time()
        with self._lock:
            self.births.add(device)
            self.birth_times.setdefault(device, received)
            self.dbirths[device] += 1
            self._pending.append((received, "DBIRTH", device, data))

    def _settle(self) -> None:
        """Decode what arrived since the last call, in order (a DBIRTH's aliases hold for the DDATAs after it)."""
        with self._lock:
            pending, self._pending = self._pending, []
        for received, kind, device, data in pending:
            if kind == "DBIRTH":
                self._aliases(device, data)
            else:
                self._decode_ddata(device, data, received)

    def _decode_ddata(self, device: str, data: bytes, received: float) -> None:
        payload = Payload.FromString(data)
        metrics = payload.metrics
        if not metrics:
            return
        read_at = metrics[0].timestamp / 1000 - (self.cnc_offset(device) if self.cnc_offset else 0.0)  # host clock
        sample = received - read_at
        published = payload.timestamp / 1000  # the gateway's clock when it encoded the message
        stamp_alias = self._stamp_alias.get(device)
        clock_alias = self._clock_alias.get(device)
        change = error = None
        for metric in metrics:
            if metric.alias == stamp_alias:
                change = stamp_latency(metric.double_value, received)
            elif metric.alias == clock_alias and not metric.is_null:
                error = clock_macro_error(metric.timestamp / 1000, metric.double_value)
        with self._lock:
            self.values += len(metrics)
            self.messages += 1
            self.sample_latency_s.append(sample)
            self.in_gateway_s.append(published - read_at)
            self.to_subscriber_s.append(received - published)
            if change is not None:
                self.change_latency_s.append(change)
            if error is not None:
                self.stamp_error_s.append(error)

    def _aliases(self, device: str, data: bytes) -> None:
        for metric in Payload.FromString(data).metrics:
            if metric.name == self.stamp_metric:
                self._stamp_alias[device] = metric.alias
            elif metric.name == self.clock_metric:
                self._clock_alias[device] = metric.alias

    def _node(self, kind: str, data: bytes) -> None:
        payload = Payload.FromString(data)
        for metric in payload.metrics:
            if kind == "NBIRTH":
                self._node_aliases[metric.alias] = metric.name
            name = metric.name or self._node_aliases.get(metric.alias, "")
            if name == OVERRUNS_METRIC:
                self.overruns = int(metric.long_value)

    def take(self) -> tuple[list[float], list[float]]:
        """The latencies recorded so far (and forget them, with the stamp errors)."""
        self._settle()
        with self._lock:
            change, sample = self.change_latency_s, self.sample_latency_s
            self.change_latency_s, self.sample_latency_s, self.stamp_error_s = [], [], []
            self.in_gateway_s, self.to_subscriber_s = [], []
        return change, sample

    def take_value_counts(self) -> tuple[int, int]:
        """(values, DDATA messages) recorded so far; forgotten after."""
        self._settle()
        with self._lock:
            counts = self.values, self.messages
            self.values = self.messages = 0
        return counts

    def take_sample_split(self) -> tuple[list[float], list[float]]:
        """The two parts of `sample` recorded so far: (in the gateway, to the subscriber); forgotten after."""
        self._settle()
        with self._lock:
            split = self.in_gateway_s, self.to_subscriber_s
            self.in_gateway_s, self.to_subscriber_s = [], []
        return split

    def take_stamp_errors(self) -> list[float]:
        """Timestamp minus simulator clock, seconds, per clock-macro value recorded so far (and forget them)."""
        self._settle()
        with self._lock:
            errors, self.stamp_error_s = self.stamp_error_s, []
        return errors
