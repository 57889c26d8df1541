"""JSON topics against a real mosquitto: retained state, events, online/offline with the gateway Will, commands."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from edge.publish import CommandSource, Publisher, PublishSettings
from edge.samples import MetricSpec, MetricType, Quality, Sample
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

TS = 1_700_000_000_123  # 2023-11-14T22:13:20.123Z
SPECS = [MetricSpec("Status/Run", MetricType.INT16), MetricSpec("Spindle/1/Speed", MetricType.DOUBLE, "rpm")]


@pytest.fixture
def observer(mosquitto: Mosquitto) -> Iterator[Observer]:
    obs = Observer(mosquitto, topics=("focas/#",))
    yield obs
    obs.close()


@pytest.fixture
async def make_publisher(mosquitto: Mosquitto, tmp_path: Path) -> AsyncIterator[Callable[..., Publisher]]:
    made: list[Publisher] = []

    def make(protocol: str = "3.1.1") -> Publisher:
        settings = PublishSettings(host=mosquitto.host, port=mosquitto.port, protocol=protocol,  # type: ignore[arg-type]
                                   formats=frozenset({"json", "sparkplug"}), json_prefix="focas",
                                   client_id="edge-json-test", state_dir=tmp_path, keepalive=5,
                                   reconnect_min_s=0.05, reconnect_max_s=0.3)
        pub = Publisher(settings)
        made.append(pub)
        return pub

    yield make
    for pub in made:
        await pub.stop()


def doc(m: object) -> dict[str, object]:
    return json.loads(m.payload)  # type: ignore[attr-defined]


async def test_state_events_online_and_gateway_will(make_publisher: Callable[..., Publisher],
                                                    observer: Observer) -> None:
    pub = make_publisher()
    await pub.start()
    assert await pub.wait_ready()
    await observer.wait_topic("focas/_gateway/online")
    assert observer.on("focas/_gateway/online")[-1].payload == b"online"

    await pub.device_online("cnc1", SPECS, [Sample("Status/Run", 3, MetricType.INT16, TS)])
    online = (await observer.wait_topic("focas/cnc1/online"))[-1]
    assert online.payload == b"online"
    await pub.device_data("cnc1", [Sample("Spindle/1/Speed", float("nan"), MetricType.DOUBLE, TS, Quality.BAD)])
    speed = (await observer.wait_topic("focas/cnc1/state/Spindle/1/Speed"))[-1]
    speed_doc = doc(speed)
    assert isinstance(speed_doc.pop("seq"), int)  # per-message sequence for consumer dedup
    assert speed_doc == {"value": None, "quality": "BAD", "timestamp": "2023-11-14T22:13:20.123Z",
                         "ts": TS, "type": "Double"}
    await pub.device_events("cnc1", [Sample("Alarm/Event", {"number": 1001, "raised": True},
                                            MetricType.STRING, TS - 5000, historical=True)])
    event = (await observer.wait_topic("focas/cnc1/events/alarm"))[-1]
    assert not event.retain
    assert doc(event)["value"] == {"number": 1001, "raised": True} and doc(event)["ts"] == TS - 5000
    assert doc(event)["historical"] is True and doc(event)["name"] == "Alarm/Event"

    # Retained: a late subscriber gets the state and the online flag.
    late = Observer(observer.broker, topics=("focas/cnc1/#",))
    try:
        await late.wait_topic("focas/cnc1/state/Status/Run")
        await late.wait_topic("focas/cnc1/online")
        assert all(m.retain for m in late.snapshot())
        assert doc(late.on("focas/cnc1/state/Status/Run")[-1])["value"] == 3
    finally:
        late.close()

    pub.drop_connections()  # crash: the broker publishes the JSON connection's Will
    await async_wait_for(lambda: any(m.payload == b"offline" for m in observer.on("focas/_gateway/online")),
                         message="gateway Will offline")
    await async_wait_for(lambda: pub.ready, message="reconnected")
    await async_wait_for(lambda: observer.on("focas/_gateway/online")[-1].payload == b"online",
                         message="gateway online again")

    await pub.device_offline("cnc1")
    await async_wait_for(lambda: observer.on("focas/cnc1/online")[-1].payload == b"offline",
                         message="machine offline")
    await pub.stop()
    await async_wait_for(lambda: observer.on("focas/_gateway/online")[-1].payload == b"offline",
                         message="gateway offline on stop")


@pytest.mark.parametrize("protocol", ["3.1.1", "5"])
async def test_json_command_and_reply(make_publisher: Callable[..., Publisher], observer: Observer,
                                      mosquitto: Mosquitto, protocol: str) -> None:
    pub = make_publisher(protocol)
    got: list[tuple[str, bytes, CommandSource]] = []

    async def on_cmd(machine: str, payload: bytes, source: CommandSource) -> None:
        got.append((machine, payload, source))
        await pub.publish_json_reply(machine, {"ok": True, "echo": json.loads(payload)}, source)

    pub.on_json_command = on_cmd
    await pub.start()
    assert await pub.wait_ready()
    await async_wait_for(lambda: pub.counters["json_connects"] == 1)

    requester = paho.Client(CallbackAPIVersion.VERSION2, client_id="requester", protocol=paho.MQTTv5)
    replies: list[paho.MQTTMessage] = []
    requester.on_message = lambda c, u, m: replies.append(m)
    requester.connect(mosquitto.host, mosquitto.port)
    requester.loop_start()
    try:
        requester.subscribe([("app/replies", 1)])
        await observer.publish("focas/cnc1/cmd", b'{"write": 1}')
        await async_wait_for(lambda: len(got) == 1, message="JSON command delivered")
        assert got[0][0] == "cnc1" and got[0][1] == b'{"write": 1}' and got[0][2].format == "json"
        reply = (await observer.wait_topic("focas/cnc1/cmd/reply"))[-1]
        assert doc(reply) == {"ok": True, "echo": {"write": 1}}

        if protocol == "5":
            props = Properties(PacketTypes.PUBLISH)
            props.ResponseTopic = "app/replies"
            props.CorrelationData = b"req-42"
            requester.publish("focas/cnc1/cmd", b'{"write": 2}', qos=1, properties=props)
            await async_wait_for(lambda: len(replies) == 1, message="reply on the response topic")
            assert got[1][2].response_topic == "app/replies" and got[1][2].correlation_data == b"req-42"
            assert replies[0].properties.CorrelationData == b"req-42"  # type: ignore[union-attr]
            assert json.loads(replies[0].payload) == {"ok": True, "echo": {"write": 2}}
    finally:
        requester.disconnect()
        requester.loop_stop()
