"""A test subscriber that records every message (in arrival order) and decodes Sparkplug payloads."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from edge.publish import payload as pl
from edge.publish.sparkplug_b_pb2 import Payload
from tests.helpers import Mosquitto, async_wait_for


@dataclass
class Received:
    topic: str
    payload: bytes
    qos: int
    retain: bool

    @property
    def kind(self) -> str:
        """Sparkplug message type (NBIRTH, DDATA, ...) or '' for other topics."""
        parts = self.topic.split("/")
        return parts[2] if len(parts) > 2 and parts[0] == "spBv1.0" else ""

    def spb(self) -> Payload:
        return pl.decode(self.payload)


class Observer:
    """Subscribes to `topics` (QoS 1), reconnecting and resubscribing when the broker restarts."""

    def __init__(self, broker: Mosquitto, topics: tuple[str, ...] = ("spBv1.0/#", "focas/#"),
                 username: str | None = None, password: str | None = None) -> None:
        self.topics = topics
        self.broker = broker
        self.messages: list[Received] = []
        self._lock = threading.Lock()
        self._subscribed = threading.Event()
        self.client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"observer-{id(self)}")
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *a: self._subscribed.set()
        self.client.on_message = self._on_message
        if username is not None:
            self.client.username_pw_set(username, password)
        self.client.reconnect_delay_set(0.05, 0.2)  # type: ignore[arg-type]
        self.client.connect_async(broker.host, broker.port, keepalive=5)
        self.client.loop_start()
        assert self._subscribed.wait(10), "observer did not subscribe"

    def _on_connect(self, client: paho.Client, *args: Any) -> None:
        self._subscribed.clear()
        client.subscribe([(t, 1) for t in self.topics])

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        with self._lock:
            self.messages.append(Received(msg.topic, bytes(msg.payload), msg.qos, bool(msg.retain)))

    def expect_reconnect(self) -> None:
        """Call before taking the broker down, then wait_resubscribed()."""
        self._subscribed.clear()

    async def wait_resubscribed(self, timeout: float = 15.0) -> None:
        await async_wait_for(self._subscribed.is_set, timeout, message="observer resubscribed")

    def snapshot(self) -> list[Received]:
        with self._lock:
            return list(self.messages)

    def of(self, kind: str) -> list[Received]:
        return [m for m in self.snapshot() if m.kind == kind]

    def on(self, topic: str) -> list[Received]:
        return [m for m in self.snapshot() if m.topic == topic]

    async def wait_count(self, kind: str, count: int, timeout: float = 10.0) -> list[Received]:
        await async_wait_for(lambda: len(self.of(kind)) >= count, timeout, message=f"{count} x {kind}")
        return self.of(kind)

    async def wait_topic(self, topic: str, count: int = 1, timeout: float = 10.0) -> list[Received]:
        await async_wait_for(lambda: len(self.on(topic)) >= count, timeout, message=f"{count} x {topic}")
        return self.on(topic)

    async def publish(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> None:
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        await async_wait_for(info.is_published, 5, message=f"PUBACK for {topic}")

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def metrics_by_name(p: Payload) -> dict[str, Payload.Metric]:
    return {m.name: m for m in p.metrics}


def properties(m: Payload.Metric) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in zip(m.properties.keys, m.properties.values, strict=True):
        out[key] = getattr(value, value.WhichOneof("value") or "is_null")
    return out
