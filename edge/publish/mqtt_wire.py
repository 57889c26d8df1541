"""MQTT PUBLISH packets at QoS 0, encoded here instead of by paho (MQTT 3.1.1 §3.3, MQTT 5 §3.3).

Why: Sparkplug DATA is nearly all of a gateway's traffic, and paho's publish costs about 7 us per message
(a message-info object with its lock, logging hooks, one send() each). A QoS 0 PUBLISH is just a fixed
header, the topic and the payload, so edge.publish.mqtt builds it and hands a loop turn's worth to paho's
write queue as one raw packet. tests/unit/publish/test_mqtt_wire.py checks the bytes against paho's own.

Layout: first byte 0x30 | retain; remaining length (base-128, at most 4 bytes); topic length (u16 BE);
topic (UTF-8); MQTT 5 only: property length 0; payload. No packet identifier at QoS 0.
"""

from __future__ import annotations

import inspect

import paho.mqtt.client as paho
from paho import mqtt as paho_package

from edge.publish.ddata import varint

MAX_REMAINING_LENGTH = 268_435_455  # four length bytes
MAX_TOPIC_BYTES = 65_535
_PUBLISH = 0x30
_RETAIN = 0x01
# paho's write queue takes raw packets; command 0 means "no callbacks when written" (not a PUBLISH, not
# a DISCONNECT). This is private API: pyproject.toml pins paho-mqtt to the minor versions it was checked
# against, tests/unit/publish/test_mqtt_wire.py fails when its shape changes, and a paho without it turns the fast
# path off with a WARNING (edge.publish.mqtt) rather than failing at the first publish.
PAHO_VERSION: str = paho_package.__version__
PRIVATE_QUEUE_PARAMETERS = ("self", "command", "packet", "mid", "qos", "info")


def private_api_problem(client_class: type = paho.Client) -> str | None:
    """What is wrong with paho's private write queue for our use, or None when it has the known shape."""
    method = getattr(client_class, "_packet_queue", None)
    if not callable(method):
        return "paho.Client._packet_queue is missing"
    try:
        names = tuple(inspect.signature(method).parameters)
    except (TypeError, ValueError) as exc:
        return f"paho.Client._packet_queue has no readable signature ({exc})"
    if names != PRIVATE_QUEUE_PARAMETERS:
        return f"paho.Client._packet_queue takes {names}, expected {PRIVATE_QUEUE_PARAMETERS}"
    return None


PROBLEM = private_api_problem()
AVAILABLE = PROBLEM is None

Prefix = tuple[bytes, bytes]  # (first byte, variable header: topic and, for MQTT 5, property length)


def remaining_length(n: int) -> bytes:
    """MQTT's remaining length: the same base-128 varint as protobuf's, at most four bytes."""
    if not 0 <= n <= MAX_REMAINING_LENGTH:
        raise ValueError(f"MQTT packet of {n} bytes is over the {MAX_REMAINING_LENGTH}-byte limit")
    return varint(n)


class TopicCache:
    """The encoded fixed byte and variable header of each topic, built once; None for topics paho must
    judge (wildcards, NUL, empty, too long, not encodable), so its error stays the one callers see."""

    def __init__(self, *, v5: bool) -> None:
        self._v5 = v5
        self._prefixes: dict[tuple[str, bool], Prefix | None] = {}

    def prefix(self, topic: str, retain: bool) -> Prefix | None:
        key = (topic, retain)
        try:
            return self._prefixes[key]
        except KeyError:
            pass
        found = self._encode(topic, retain) if AVAILABLE else None
        if len(self._prefixes) >= 100_000:  # topics are per device and kind; a leak guard, not an LRU
            self._prefixes.clear()
        self._prefixes[key] = found
        return found

    def _encode(self, topic: str, retain: bool) -> Prefix | None:
        if not topic or "+" in topic or "#" in topic or "\x00" in topic:
            return None
        try:
            data = topic.encode("utf-8")
        except UnicodeEncodeError:
            return None
        if len(data) > MAX_TOPIC_BYTES:
            return None
        header = len(data).to_bytes(2, "big") + data + (b"\x00" if self._v5 else b"")
        return bytes((_PUBLISH | (_RETAIN if retain else 0),)), header


def publish_packet(prefix: Prefix, payload: bytes) -> bytes:
    first, header = prefix
    return first + remaining_length(len(header) + len(payload)) + header + payload


def queue_raw(client: paho.Client, data: bytes) -> None:
    """Append already-encoded packets to paho's write queue (it writes them in order with its own)."""
    client._packet_queue(0, data, 0, 0)


def held_bytes(client: paho.Client) -> int:
    """Bytes paho holds for the broker: its write queue's not yet taken by the kernel, and the payloads of
    QoS 1 messages not yet acknowledged (sent, or queued behind paho's in-flight limit). Its private
    queues; 0 if they have another shape (then nothing waits for them to drain)."""
    try:
        return (sum(packet["to_process"] for packet in client._out_packet)
                + sum(len(message.payload) for message in client._out_messages.values()))
    except (AttributeError, KeyError, TypeError):
        return 0
