"""Sparkplug B edge-node session against a real mosquitto, modelled on the TCK edge tests (sparkplug.md §2.3).

Every check decodes what an independent subscriber received.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path

import pytest

from edge.publish import CommandSource, DeviceCommands, Publisher, PublishSettings
from edge.publish import payload as pl
from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.samples import MetricSpec, MetricType, Quality, Sample
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.mqtt_observer import Observer, Received, metrics_by_name, properties

pytestmark = pytest.mark.integration

GROUP, EDGE = "Plant1", "gw1"
PROTOCOLS = ["3.1.1", "5"]

SPECS = [
    MetricSpec("Status/Run", MetricType.INT16),
    MetricSpec("Spindle/1/Speed", MetricType.DOUBLE, unit="rpm"),
    MetricSpec("Macro/500", MetricType.DOUBLE, writable=True),
    MetricSpec("Counters/Parts", MetricType.UINT32),
    MetricSpec("Program/Number", MetricType.INT32, writable=False),
    MetricSpec("Alarm/Event", MetricType.STRING),
]
TS = 1_700_000_000_000
REBIRTH = Payload(metrics=[Payload.Metric(name=pl.REBIRTH_METRIC, boolean_value=True)]).SerializeToString()


def samples(ts: int = TS, speed: float = 1200.0) -> list[Sample]:
    return [
        Sample("Status/Run", 3, MetricType.INT16, ts),
        Sample("Spindle/1/Speed", speed, MetricType.DOUBLE, ts),
        Sample("Macro/500", 1.5, MetricType.DOUBLE, ts),
        Sample("Counters/Parts", 4_000_000_000, MetricType.UINT32, ts),
    ]


def topic(kind: str, device: str | None = None) -> str:
    base = f"spBv1.0/{GROUP}/{kind}/{EDGE}"
    return f"{base}/{device}" if device else base


@pytest.fixture
def observer(mosquitto: Mosquitto) -> Iterator[Observer]:
    obs = Observer(mosquitto)
    yield obs
    obs.close()


@pytest.fixture
async def make_publisher(mosquitto: Mosquitto, tmp_path: Path) -> AsyncIterator[Callable[..., Publisher]]:
    made: list[Publisher] = []

    def make(protocol: str = "3.1.1", **overrides: object) -> Publisher:
        settings = PublishSettings(host=mosquitto.host, port=mosquitto.port, protocol=protocol,  # type: ignore[arg-type]
                                   formats=frozenset({"sparkplug"}), group_id=GROUP, edge_node_id=EDGE,
                                   client_id=f"edge-{len(made)}", state_dir=tmp_path / "state", keepalive=5,
                                   reconnect_min_s=0.05, reconnect_max_s=0.3, rebirth_min_interval_s=0.3)
        for key, value in overrides.items():
            setattr(settings, key, value)
        pub = Publisher(settings)
        made.append(pub)
        return pub

    yield make
    for pub in made:
        await pub.stop()


def check_seq_chain(messages: list[Received]) -> None:
    """One seq counter for all node and device messages: NBIRTH 0, then +1 mod 256; NDEATH has none."""
    expected: int | None = None
    for m in messages:
        if m.kind in ("NDEATH", "NCMD", "DCMD", ""):
            continue
        p = m.spb()
        assert p.HasField("seq"), f"{m.kind} without seq"
        if m.kind == "NBIRTH":
            assert p.seq == 0
        elif expected is not None:
            assert p.seq == expected, f"{m.kind} seq {p.seq}, expected {expected}"
        expected = (p.seq + 1) % 256


def bdseq_of(m: Received) -> int:
    found = metrics_by_name(m.spb())[pl.BDSEQ_METRIC]
    assert found.datatype == DataType.Int64 and found.WhichOneof("value") == "long_value"
    return found.long_value


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_session_establishment(make_publisher: Callable[..., Publisher], observer: Observer,
                                     protocol: str) -> None:
    pub = make_publisher(protocol)
    pub.set_node_metrics([Sample("Gateway/Version", "0.1.0", MetricType.STRING, TS)])
    await pub.device_online("cnc1", SPECS, samples())
    await pub.start()
    nbirth = (await observer.wait_count("NBIRTH", 1))[0]
    dbirth = (await observer.wait_count("DBIRTH", 1))[0]
    assert nbirth.topic == topic("NBIRTH") and nbirth.qos == 0 and not nbirth.retain
    assert dbirth.topic == topic("DBIRTH", "cnc1") and dbirth.qos == 0 and not dbirth.retain

    nb = nbirth.spb()
    assert nb.seq == 0 and nb.HasField("timestamp")
    assert bdseq_of(nbirth) == 0  # fresh state dir: the first CONNECT carries 0
    rebirth = metrics_by_name(nb)[pl.REBIRTH_METRIC]
    assert rebirth.datatype == DataType.Boolean and rebirth.boolean_value is False
    assert not rebirth.HasField("alias")
    assert metrics_by_name(nb)["Gateway/Version"].string_value == "0.1.0"

    db = dbirth.spb()
    assert db.seq == 1
    by_name = metrics_by_name(db)
    assert set(by_name) == {s.name for s in SPECS}
    for m in db.metrics:
        assert m.HasField("alias") and m.HasField("datatype") and m.HasField("timestamp")
    assert properties(by_name["Spindle/1/Speed"]) == {"engUnit": "rpm", "Quality": 192}
    assert by_name["Counters/Parts"].WhichOneof("value") == "long_value"  # UInt32 in long_value
    assert by_name["Counters/Parts"].long_value == 4_000_000_000
    assert by_name["Spindle/1/Speed"].timestamp == TS  # the CNC's time, not ours
    assert by_name["Alarm/Event"].is_null and by_name["Alarm/Event"].WhichOneof("value") is None
    aliases = [m.alias for p in (nb, db) for m in p.metrics if m.HasField("alias")]
    assert len(aliases) == len(set(aliases)), "aliases unique across the node"

    # The NCMD subscription exists before the NBIRTH: a rebirth sent the moment we see NBIRTH is obeyed.
    req = Payload(metrics=[Payload.Metric(name=pl.REBIRTH_METRIC, datatype=DataType.Boolean, boolean_value=True)])
    await observer.publish(topic("NCMD"), req.SerializeToString())
    second = (await observer.wait_count("NBIRTH", 2))[1]
    assert bdseq_of(second) == 0 and second.spb().seq == 0

    # Will: NDEATH, QoS 1, not retained, only bdSeq (Int64), no seq; the broker sends it on socket loss.
    pub.drop_connections()
    ndeath = (await observer.wait_count("NDEATH", 1))[0]
    assert ndeath.topic == topic("NDEATH") and ndeath.qos == 1 and not ndeath.retain
    nd = ndeath.spb()
    assert not nd.HasField("seq") and [m.name for m in nd.metrics] == [pl.BDSEQ_METRIC]
    assert bdseq_of(ndeath) == 0
    # ...and the node reconnects by itself with the next bdSeq.
    third = (await observer.wait_count("NBIRTH", 3))[2]
    assert bdseq_of(third) == 1 and third.spb().seq == 0
    check_seq_chain(observer.snapshot())


async def test_bdseq_survives_broker_restart_and_daemon_restart(
        make_publisher: Callable[..., Publisher], observer: Observer, mosquitto: Mosquitto) -> None:
    pub = make_publisher("5")
    await pub.start()
    first = (await observer.wait_count("NBIRTH", 1))[0]
    assert bdseq_of(first) == 0
    observer.expect_reconnect()
    mosquitto.stop()
    mosquitto.start()  # same port; the publisher reconnects on its own (backoff), so does the observer
    await observer.wait_resubscribed()
    await async_wait_for(lambda: pub.counters["sparkplug_connects"] == 2 and pub.session_state == "born",
                         timeout=15, message="automatic reconnect and birth")
    # The new NBIRTH may have beaten the observer's own reconnect; ask for a rebirth to see one.
    await observer.publish(topic("NCMD"), REBIRTH)
    second = (await observer.wait_count("NBIRTH", 2))[-1]
    assert bdseq_of(second) == pub.bdseq == 1  # the Will and NBIRTH of the second CONNECT
    assert second.spb().seq == 0
    before = len(observer.of("NDEATH"))  # the broker sent the first Will (bdSeq 0) when it went down
    await pub.stop()
    ndeath = (await observer.wait_count("NDEATH", before + 1))[before]
    assert bdseq_of(ndeath) == bdseq_of(second)

    births = len(observer.of("NBIRTH"))  # 2 or 3: the automatic NBIRTH may or may not have been seen
    restarted = make_publisher("5")  # same state_dir: bdSeq continues from disk
    await restarted.start()
    third = (await observer.wait_count("NBIRTH", births + 1))[births]
    assert bdseq_of(third) == (bdseq_of(second) + 1) % 256


async def test_send_data_alias_only_timestamps_and_seq_wrap(make_publisher: Callable[..., Publisher],
                                                            observer: Observer) -> None:
    pub = make_publisher()
    await pub.device_online("cnc1", SPECS, samples())
    await pub.start()
    dbirth = (await observer.wait_count("DBIRTH", 1))[0]
    alias = {m.name: m.alias for m in dbirth.spb().metrics}

    await pub.device_data("cnc1", [Sample("Spindle/1/Speed", 99.5, MetricType.DOUBLE, TS + 7),
                                   Sample("Status/Run", -2, MetricType.INT16, TS + 5, Quality.STALE)])
    ddata = (await observer.wait_count("DDATA", 1))[0]
    assert ddata.topic == topic("DDATA", "cnc1") and ddata.qos == 0 and not ddata.retain
    p = ddata.spb()
    for m in p.metrics:
        assert not m.HasField("name") and not m.HasField("datatype") and m.HasField("alias")
    assert [m.timestamp for m in p.metrics] == [TS + 5, TS + 7]  # chronological, CNC time preserved
    run, speed = p.metrics
    assert run.alias == alias["Status/Run"] and run.int_value == (-2) & 0xFFFFFFFF
    assert properties(run) == {"Quality": 500}
    assert speed.alias == alias["Spindle/1/Speed"] and speed.double_value == 99.5 and not properties(speed)

    for i in range(300):
        await pub.device_data("cnc1", [Sample("Spindle/1/Speed", float(i), MetricType.DOUBLE, TS + 100 + i)])
    await observer.wait_count("DDATA", 301)
    seqs = [m.spb().seq for m in observer.snapshot() if m.kind != ""]
    assert 255 in seqs and seqs[seqs.index(255) + 1] == 0
    check_seq_chain(observer.snapshot())
    assert pub.counters["dropped"] == 0


async def test_rebirth_same_bdseq_no_data_between_and_bursts_coalesced(
        make_publisher: Callable[..., Publisher], observer: Observer) -> None:
    pub = make_publisher()
    await pub.device_online("cnc1", SPECS, samples())
    await pub.device_online("cnc2", SPECS[:2], [])
    await pub.start()
    await observer.wait_count("DBIRTH", 2)
    req = Payload(metrics=[Payload.Metric(name=pl.REBIRTH_METRIC, boolean_value=True)]).SerializeToString()

    await observer.publish(topic("NCMD"), req)
    for i in range(20):  # data keeps flowing while the rebirth happens
        await pub.device_data("cnc1", [Sample("Spindle/1/Speed", float(i), MetricType.DOUBLE, TS + i)])
    await observer.wait_count("DBIRTH", 4)
    msgs = [m for m in observer.snapshot() if m.kind]
    nbirths = [i for i, m in enumerate(msgs) if m.kind == "NBIRTH"]
    assert len(nbirths) == 2
    after = msgs[nbirths[1]:nbirths[1] + 3]
    assert [m.kind for m in after] == ["NBIRTH", "DBIRTH", "DBIRTH"], "births come together, no DATA inside"
    assert bdseq_of(msgs[nbirths[1]]) == bdseq_of(msgs[nbirths[0]])
    check_seq_chain(msgs)
    # The rebirth DBIRTH carries the latest value (the data was not lost, it is in the birth or after it).
    await async_wait_for(lambda: pub.counters["rebirths"] == 1)

    for _ in range(6):
        await observer.publish(topic("NCMD"), req)
    await async_wait_for(lambda: pub.counters["rebirth_requests"] == 7, message="7 rebirth requests")
    await async_wait_for(lambda: pub.session_state == "born", message="rebirths done")
    await async_wait_for(lambda: len(observer.of("NBIRTH")) == 1 + pub.counters["rebirths"],
                         message="every rebirth's NBIRTH observed")
    births = len(observer.of("NBIRTH"))
    assert 3 <= births <= 4, f"6 requests coalesced into one or two rebirths, got {births - 2}"
    assert pub.counters["rebirths_coalesced"] >= 4
    check_seq_chain(observer.snapshot())


async def test_dcmd_by_name_and_alias_reaches_callback_unknown_counted(
        make_publisher: Callable[..., Publisher], observer: Observer) -> None:
    pub = make_publisher()
    received: list[tuple[str, str, object, CommandSource]] = []

    async def on_command(commands: DeviceCommands, source: CommandSource) -> None:
        received.extend((commands.device_id, name, value, source) for name, value in commands.writes)

    pub.on_device_command = on_command
    await pub.device_online("cnc1", SPECS, samples())
    await pub.start()
    dbirth = (await observer.wait_count("DBIRTH", 1))[0]
    alias = {m.name: m.alias for m in dbirth.spb().metrics}
    dcmd = topic("DCMD", "cnc1")

    by_name = Payload(metrics=[Payload.Metric(name="Macro/500", datatype=DataType.Double, double_value=2.5)])
    await observer.publish(dcmd, by_name.SerializeToString())
    by_alias = Payload(metrics=[Payload.Metric(alias=alias["Macro/500"], double_value=-7.0)])
    await observer.publish(dcmd, by_alias.SerializeToString())
    await async_wait_for(lambda: len(received) == 2, message="two DCMDs delivered")
    assert [(d, n, v) for d, n, v, _ in received] == [("cnc1", "Macro/500", 2.5), ("cnc1", "Macro/500", -7.0)]
    assert received[0][3] == CommandSource("sparkplug", dcmd)

    unknown = Payload(metrics=[Payload.Metric(alias=999_999, double_value=1.0)])
    await observer.publish(dcmd, unknown.SerializeToString())
    await async_wait_for(lambda: pub.counters["unknown_commands"] == 1, message="unknown alias counted")
    read_only = Payload(metrics=[Payload.Metric(name="Program/Number", int_value=5)])
    await observer.publish(dcmd, read_only.SerializeToString())
    await async_wait_for(lambda: pub.counters["rejected_commands"] == 1, message="read-only rejected")
    assert len(received) == 2


def state(online: bool, ts: int) -> bytes:
    return json.dumps({"online": online, "timestamp": ts}).encode()


async def test_primary_host_gating_and_stale_state(make_publisher: Callable[..., Publisher],
                                                   observer: Observer) -> None:
    pub = make_publisher("5", primary_host_id="SCADA")
    await pub.device_online("cnc1", SPECS, samples())
    state_topic = "spBv1.0/STATE/SCADA"
    await pub.start()
    await async_wait_for(lambda: pub.session_state == "waiting_for_host", message="subscribed, waiting")
    await observer.publish("spBv1.0/STATE/OTHER", state(True, 5000), retain=True)  # another host: no birth
    await observer.publish(state_topic, state(False, 900), retain=True)
    await async_wait_for(lambda: pub.counters["stale_state_ignored"] == 0 and pub._spb.host is not None
                         and pub._spb.host.last_timestamp == 900, message="offline STATE seen")
    assert observer.of("NBIRTH") == [] and pub.session_state == "waiting_for_host"

    await observer.publish(state_topic, state(True, 1000), retain=True)
    nbirth = (await observer.wait_count("NBIRTH", 1))[0]
    await observer.wait_count("DBIRTH", 1)
    assert bdseq_of(nbirth) == 0

    await observer.publish(state_topic, state(False, 500), retain=True)  # stale host Will: ignored
    await async_wait_for(lambda: pub.counters["stale_state_ignored"] == 1, message="stale offline ignored")
    assert observer.of("NDEATH") == [] and pub.session_state == "born"

    await observer.publish(state_topic, state(False, 2000), retain=True)  # valid offline: NDEATH, reconnect
    ndeath = (await observer.wait_count("NDEATH", 1))[0]
    assert bdseq_of(ndeath) == 0
    await async_wait_for(lambda: pub.session_state == "waiting_for_host" and pub.bdseq == 1,
                         message="reconnected, waiting for the host")
    await observer.publish(state_topic, state(True, 1500), retain=True)  # older than 2000: ignored
    await async_wait_for(lambda: pub.counters["stale_state_ignored"] == 2, message="stale online ignored")
    assert len(observer.of("NBIRTH")) == 1

    await observer.publish(state_topic, state(True, 3000), retain=True)
    second = (await observer.wait_count("NBIRTH", 2))[1]
    assert bdseq_of(second) == 1 and second.spb().seq == 0
    await observer.wait_count("DBIRTH", 2)


@pytest.mark.parametrize("protocol", PROTOCOLS)
async def test_session_termination(make_publisher: Callable[..., Publisher], observer: Observer,
                                   protocol: str) -> None:
    pub = make_publisher(protocol)
    await pub.device_online("cnc1", SPECS, samples())
    await pub.device_online("cnc2", SPECS, samples())
    await pub.start()
    await observer.wait_count("DBIRTH", 2)
    await pub.device_offline("cnc2")
    await observer.wait_count("DDEATH", 1)
    await pub.stop()
    expected_ndeaths = 2 if protocol == "5" else 1  # MQTT 5 reason 0x04: the broker sends the Will as well
    await observer.wait_count("NDEATH", expected_ndeaths)
    msgs = [m for m in observer.snapshot() if m.kind]
    kinds = [m.kind for m in msgs]
    assert kinds[:3] == ["NBIRTH", "DBIRTH", "DBIRTH"]
    assert kinds[3:6] == ["DDEATH", "DDEATH", "NDEATH"]
    assert {m.topic for m in msgs if m.kind == "DDEATH"} == {topic("DDEATH", "cnc1"), topic("DDEATH", "cnc2")}
    ddeath = msgs[4].spb()
    assert ddeath.HasField("seq") and ddeath.HasField("timestamp")
    assert {bdseq_of(m) for m in msgs if m.kind == "NDEATH"} == {0}
    check_seq_chain(msgs)
    assert not pub.connected


async def test_dbirths_go_out_over_loop_turns_with_live_data_between(
        make_publisher: Callable[..., Publisher], observer: Observer, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The DBIRTHs after an NBIRTH go out over several loop turns (each its own turn here), live data flowing
    between them: a device's DDATA only after its own DBIRTH, the seq one chain, and the ticks of a device
    not yet born spooled and replayed (historical) after its DBIRTH, or carried by it."""
    from edge.publish import sparkplug_session
    from edge.publish.spool import DiskSpool

    monkeypatch.setattr(sparkplug_session, "BIRTH_SLICE_S", 0.0)
    devices = [f"cnc{i}" for i in range(30)]
    spool = DiskSpool(tmp_path / "spool.sqlite")
    pub = make_publisher()
    pub = Publisher(pub.settings, spool=spool)
    for device_id in devices:
        await pub.device_online(device_id, SPECS, samples())
    await pub.start()
    sent: dict[str, list[float]] = {d: [] for d in devices}
    tick = 0
    while len(observer.of("DBIRTH")) < len(devices):
        tick += 1
        for device_id in devices:
            speed = float(tick)
            sent[device_id].append(speed)
            await pub.device_data(device_id, [Sample("Spindle/1/Speed", speed, MetricType.DOUBLE, TS + tick)])
        await asyncio.sleep(0.002)
        assert tick < 5_000, "every DBIRTH within ~10 s"
    await async_wait_for(lambda: spool.pending() == 0, message="the spooled ticks replayed")
    await pub.stop()

    msgs = [m for m in observer.snapshot() if m.kind in ("NBIRTH", "DBIRTH", "DDATA")]
    check_seq_chain(msgs)
    assert msgs[0].kind == "NBIRTH"
    born: set[str] = set()
    arrived: dict[str, set[float]] = {d: set() for d in devices}
    data_between = 0
    for m in msgs[1:]:
        device_id = m.topic.rsplit("/", 1)[-1]
        if m.kind == "DBIRTH":
            born.add(device_id)
            arrived[device_id].add(metrics_by_name(m.spb())["Spindle/1/Speed"].double_value)
            continue
        assert device_id in born, f"DDATA of {device_id} before its DBIRTH"
        data_between += len(born) < len(devices)
        arrived[device_id].update(metric.double_value for metric in m.spb().metrics)
    assert data_between, "live data went out between the DBIRTHs"
    for device_id in devices:
        assert set(sent[device_id]) <= arrived[device_id], f"{device_id}: every tick arrived"
