"""QoS 0 PUBLISH packets built by edge.publish.mqtt_wire are byte for byte the ones paho writes."""

from __future__ import annotations

import socket
import tomllib
from importlib.metadata import version
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from packaging.requirements import Requirement
from paho.mqtt.enums import CallbackAPIVersion

from edge.publish import mqtt_wire


def paho_bytes(protocol: int, topic: str, payload: bytes, retain: bool) -> bytes:
    """What paho itself sends for this publish, read from the other end of a socket pair."""
    client = paho.Client(CallbackAPIVersion.VERSION2, client_id="t", protocol=protocol)
    ours, theirs = socket.socketpair()
    try:
        ours.setblocking(False)
        client._sock = ours  # type: ignore[attr-defined]
        client.publish(topic, payload, qos=0, retain=retain)
        chunks = []
        theirs.settimeout(5)
        while sum(map(len, chunks)) < 5 or not _complete(b"".join(chunks)):
            client.loop_write()  # the rest, once the reader made room
            chunks.append(theirs.recv(1 << 20))
        return b"".join(chunks)
    finally:
        client._sock = None  # type: ignore[attr-defined]
        ours.close()
        theirs.close()


def _complete(data: bytes) -> bool:
    length, shift, index = 0, 0, 1
    while True:
        byte = data[index]
        length |= (byte & 0x7F) << shift
        index += 1
        if not byte & 0x80:
            return len(data) >= index + length
        shift += 7


topics = st.text(st.characters(blacklist_characters="+#\x00", blacklist_categories=("Cs",)), min_size=1,
                 max_size=40)


@settings(max_examples=60, deadline=None)
@given(topics, st.binary(max_size=300), st.booleans(), st.sampled_from([paho.MQTTv311, paho.MQTTv5]))
def test_packet_equals_paho(topic: str, payload: bytes, retain: bool, protocol: int) -> None:
    prefix = mqtt_wire.TopicCache(v5=protocol == paho.MQTTv5).prefix(topic, retain)
    assert prefix is not None
    assert mqtt_wire.publish_packet(prefix, payload) == paho_bytes(protocol, topic, payload, retain)


@pytest.mark.parametrize("size", [0, 127 - 9, 128, 16_383, 16_384, 2_097_152])
def test_remaining_length_boundaries_equal_paho(size: int) -> None:
    topic = "spBv1.0/G/DDATA/E/m1"
    payload = bytes(range(256)) * (size // 256) + bytes(size % 256)
    prefix = mqtt_wire.TopicCache(v5=False).prefix(topic, False)
    assert prefix is not None
    assert mqtt_wire.publish_packet(prefix, payload) == paho_bytes(paho.MQTTv311, topic, payload, False)


@pytest.mark.parametrize("topic", ["", "a/+/b", "a/#", "nul\x00", "x" * 65_536, "\udcff"])
def test_topics_paho_must_judge_take_the_slow_path(topic: str) -> None:
    assert mqtt_wire.TopicCache(v5=False).prefix(topic, False) is None


def test_oversized_packet_is_refused_with_its_size() -> None:
    with pytest.raises(ValueError, match="268435456"):
        mqtt_wire.remaining_length(268_435_456)


# -- the private API the fast path rests on (issue 16, point 15) ------------------------------------------

def test_installed_paho_has_the_private_write_queue_the_fast_path_uses() -> None:
    """Fails loudly on a paho whose private queue changed: re-check mqtt_wire, then move the pin."""
    assert mqtt_wire.private_api_problem() is None, (
        f"paho-mqtt {mqtt_wire.PAHO_VERSION}: {mqtt_wire.private_api_problem()}")
    assert mqtt_wire.AVAILABLE


def test_raw_packets_go_out_in_order_with_pahos_own() -> None:
    """queue_raw's bytes reach the socket, before a packet paho queues after them."""
    client = paho.Client(CallbackAPIVersion.VERSION2, client_id="t", protocol=paho.MQTTv311)
    ours, theirs = socket.socketpair()
    try:
        ours.setblocking(False)
        client._sock = ours  # type: ignore[attr-defined]
        prefix = mqtt_wire.TopicCache(v5=False).prefix("a/b", False)
        assert prefix is not None
        raw = mqtt_wire.publish_packet(prefix, b"first")
        mqtt_wire.queue_raw(client, raw)
        client.publish("a/b", b"second", qos=0)
        client.loop_write()
        theirs.settimeout(5)
        data = b""
        expected = raw + paho_bytes(paho.MQTTv311, "a/b", b"second", False)
        while len(data) < len(expected):
            data += theirs.recv(1 << 16)
        assert data == expected
    finally:
        client._sock = None  # type: ignore[attr-defined]
        ours.close()
        theirs.close()


def test_a_changed_private_queue_is_reported_not_used() -> None:
    class Renamed(paho.Client):
        def _packet_queue(self, packet: bytes) -> None:  # type: ignore[override]
            raise AssertionError("never called")

    class Missing:
        pass

    problem = mqtt_wire.private_api_problem(Renamed)
    assert problem is not None and "('self', 'packet')" in problem and "expected" in problem
    assert mqtt_wire.private_api_problem(Missing) == "paho.Client._packet_queue is missing"


def test_paho_is_pinned_to_the_checked_minor_versions() -> None:
    """A new paho minor may reshape private API: it is allowed only after the tests above pass with it.
    2.1 lacks Client.drop_out_messages (edge.publish.mqtt calls it on every CONNACK)."""
    pyproject = tomllib.loads((Path(__file__).parents[3] / "pyproject.toml").read_text())
    (spec,) = [Requirement(d) for d in pyproject["project"]["dependencies"] if d.startswith("paho-mqtt")]
    assert spec.specifier.contains(version("paho-mqtt")), "the installed paho is one the pin allows"
    checked = {"2.2.0", "2.2.9"}
    assert all(spec.specifier.contains(v) for v in checked)
    assert not any(spec.specifier.contains(v) for v in ("2.1.0", "2.3.0", "3.0.0")), spec
