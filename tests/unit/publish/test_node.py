"""The sans-IO Sparkplug session: births, seq, aliases, rebirth hold, commands, STATE, bdSeq."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.publish import payload as pl
from edge.publish.aliases import AliasMap
from edge.publish.bdseq import BdSeqCounter
from edge.publish.node import Outgoing, SparkplugNode
from edge.publish.node_commands import CommandIgnored, DeviceCommand, RebirthRequested
from edge.publish.primary_host import PrimaryHost, StateVerdict
from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.publish.state_store import StateStore
from edge.samples import MetricSpec, MetricType, Quality, Sample

SPECS = [MetricSpec("Status/Run", MetricType.INT16), MetricSpec("Macro/500", MetricType.DOUBLE, writable=True)]


def node(tmp_path: Path | None = None) -> SparkplugNode:
    store = StateStore(tmp_path) if tmp_path else None
    n = SparkplugNode("G", "E", AliasMap(store), clock=lambda: 1000)
    n.session_started(3)
    return n


def seqs(messages: list[Outgoing]) -> list[int]:
    return [pl.decode(m.payload).seq for m in messages]


def test_births_then_data_share_one_seq_counter_that_wraps() -> None:
    n = node()
    n.device_online("m1", SPECS, [Sample("Status/Run", 1, MetricType.INT16, 5)])
    births = n.births()
    assert [m.topic for m in births] == ["spBv1.0/G/NBIRTH/E", "spBv1.0/G/DBIRTH/E/m1"]
    assert seqs(births) == [0, 1]
    out = []
    for i in range(300):
        out += n.device_data("m1", [Sample("Status/Run", i, MetricType.INT16, 10 + i)])
    assert seqs(out) == [(2 + i) % 256 for i in range(300)]
    assert seqs(n.births()) == [0, 1]  # a rebirth restarts at 0


def test_data_before_birth_is_recorded_and_carried_by_the_birth() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    assert n.device_data("m1", [Sample("Macro/500", 2.5, MetricType.DOUBLE, 77, Quality.STALE)]) == []
    dbirth = pl.decode(n.births()[1].payload)
    macro = {m.name: m for m in dbirth.metrics}["Macro/500"]
    assert macro.double_value == 2.5 and macro.timestamp == 77 and pl.quality_of(macro) is Quality.STALE
    assert {m.name: m for m in dbirth.metrics}["Status/Run"].is_null


def test_quality_property_only_when_not_good_and_on_recovery() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    n.births()
    bad = pl.decode(n.device_data("m1", [Sample("Macro/500", None, MetricType.DOUBLE, 1, Quality.BAD)])[0].payload)
    assert bad.metrics[0].is_null and pl.quality_of(bad.metrics[0]) is Quality.BAD
    good = pl.decode(n.device_data("m1", [Sample("Macro/500", 1.0, MetricType.DOUBLE, 2)])[0].payload)
    assert list(good.metrics[0].properties.keys) == ["Quality"]  # back to GOOD, said once
    again = pl.decode(n.device_data("m1", [Sample("Macro/500", 2.0, MetricType.DOUBLE, 3)])[0].payload)
    assert list(again.metrics[0].properties.keys) == []


def test_unknown_metric_is_counted_not_published() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    n.births()
    out = n.device_data("m1", [Sample("Nope", 1, MetricType.INT16, 1), Sample("Status/Run", 1, MetricType.INT16, 1)])
    assert len(pl.decode(out[0].payload).metrics) == 1 and n.unknown_metrics == 1


def test_an_unknown_metric_among_known_ones_keeps_the_latest_known_values() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    n.births()
    out = n.device_data("m1", [Sample("Macro/500", 1.0, MetricType.DOUBLE, 1),
                               Sample("Nope", 1, MetricType.INT16, 1),
                               Sample("Macro/500", 2.0, MetricType.DOUBLE, 2),
                               Sample("Status/Run", 3, MetricType.INT16, 2)])
    assert len(pl.decode(out[0].payload).metrics) == 3 and n.unknown_metrics == 1
    dbirth = next(m for m in n.births() if "/DBIRTH/" in m.topic)
    values = {m.name: (m.double_value, m.int_value) for m in pl.decode(dbirth.payload).metrics}
    assert values["Macro/500"][0] == 2.0 and values["Status/Run"][1] == 3


def test_rebirth_hold_stops_data_and_replays_held_events_after_births() -> None:
    n = node()
    n.device_online("m1", [*SPECS, MetricSpec("Alarm/Event", MetricType.STRING)], [])
    n.births()
    assert n.request_rebirth() and not n.live
    assert n.device_data("m1", [Sample("Status/Run", 9, MetricType.INT16, 50)]) == []
    assert n.device_events("m1", [Sample("Alarm/Event", "raised", MetricType.STRING, 40)]) == []
    out = n.births()
    assert [m.topic.split("/")[2] for m in out] == ["NBIRTH", "DBIRTH", "DDATA"]
    assert {m.name: m.int_value for m in pl.decode(out[1].payload).metrics}["Status/Run"] == 9
    assert pl.decode(out[2].payload).metrics[0].timestamp == 40  # the event's own time


def test_held_events_are_released_after_their_dbirth_with_the_samples_their_ddata_carries() -> None:
    n = node()
    event_specs = [*SPECS, MetricSpec("Alarm/Event", MetricType.STRING)]
    n.device_online("m1", event_specs, [])
    n.device_online("m2", event_specs, [])
    n.births()
    assert n.request_rebirth()
    raised = [Sample("Alarm/Event", "raised", MetricType.STRING, 40),
              Sample("Alarm/Event", "cleared", MetricType.STRING, 45)]
    assert n.device_events("m1", raised) == []
    assert n.device_events("m2", [Sample("Alarm/Event", "other", MetricType.STRING, 41)]) == []
    n.nbirth()
    n.dbirth("m1")
    (released,) = n.release_held_events("m1")
    assert (released.device_id, list(released.samples)) == ("m1", raised)
    ddata = pl.decode(released.message.payload)
    assert released.message.topic == "spBv1.0/G/DDATA/E/m1"
    assert [(m.timestamp, m.string_value) for m in ddata.metrics] == [(40, "raised"), (45, "cleared")]
    n.device_offline("m2")
    assert n.release_held_events() == []  # m2 went offline before its DBIRTH: its events are not sent
    n.dbirth("m1")
    assert n.release_held_events("m1") == []  # taken once


def test_aliases_unique_across_devices_and_stable_across_restarts(tmp_path: Path) -> None:
    n = node(tmp_path)
    n.set_node_metrics([Sample("Gateway/Version", "1", MetricType.STRING, 1)])
    n.device_online("m1", SPECS, [])
    n.device_online("m2", SPECS, [])
    first = aliases_by_topic(n)
    assert len(set(first.values())) == len(first), "unique across node and devices"
    assert not {name for _, name in first} & {"bdSeq", pl.REBIRTH_METRIC}, "never aliased"
    again = node(tmp_path)
    again.set_node_metrics([Sample("Gateway/Version", "1", MetricType.STRING, 1)])
    again.device_online("m2", SPECS, [])  # different order after the restart
    again.device_online("m1", SPECS, [])
    assert aliases_by_topic(again) == first


def test_alias_resolution_follows_new_aliases_and_a_reload(tmp_path: Path) -> None:
    aliases = AliasMap(StateStore(tmp_path))
    a = aliases.alias("m1", "x")
    assert aliases.resolve(a) == ("m1", "x") and aliases.resolve(a + 1) is None
    b = aliases.alias("m2", "x")  # added after the reverse map was built
    assert b == a + 1 and aliases.resolve(b) == ("m2", "x")
    aliases.save()
    reloaded = AliasMap(StateStore(tmp_path))
    assert (reloaded.resolve(a), reloaded.resolve(b)) == (("m1", "x"), ("m2", "x"))
    assert reloaded.alias("m3", "y") == b + 1, "never reused after a restart"


def aliases_by_topic(n: SparkplugNode) -> dict[tuple[str, str], int]:
    return {(m.topic, metric.name): metric.alias for m in n.births()
            for metric in pl.decode(m.payload).metrics if metric.HasField("alias")}


def test_commands_rebirth_by_name_dcmd_by_name_and_alias() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    alias = {m.name: m.alias for m in pl.decode(n.births()[1].payload).metrics}
    rebirth = Payload(metrics=[Payload.Metric(name=pl.REBIRTH_METRIC, boolean_value=True)])
    assert n.parse_command("spBv1.0/G/NCMD/E", rebirth.SerializeToString()) == [RebirthRequested()]
    cmd = Payload(metrics=[Payload.Metric(name="Macro/500", double_value=1.0),
                           Payload.Metric(alias=alias["Macro/500"], double_value=2.0),
                           Payload.Metric(alias=424242, double_value=3.0),
                           Payload.Metric(name="Status/Run", int_value=1),
                           Payload.Metric(name="Macro/500", string_value="x")])
    events = n.parse_command("spBv1.0/G/DCMD/E/m1", cmd.SerializeToString())
    assert events[:2] == [DeviceCommand("m1", "Macro/500", 1.0), DeviceCommand("m1", "Macro/500", 2.0)]
    assert [(type(e), getattr(e, "unknown", None)) for e in events[2:]] == [
        (CommandIgnored, True), (CommandIgnored, False), (CommandIgnored, False)]
    assert isinstance(n.parse_command("spBv1.0/G/DCMD/E/zz", cmd.SerializeToString())[0], CommandIgnored)
    assert isinstance(n.parse_command("spBv1.0/G/NCMD/E", b"\xff\xff")[0], CommandIgnored)


@given(st.binary(max_size=200))
def test_command_parser_never_raises(data: bytes) -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    for event in n.parse_command("spBv1.0/G/DCMD/E/m1", data):
        assert isinstance(event, RebirthRequested | DeviceCommand | CommandIgnored)


def test_shutdown_ddeath_then_ndeath_with_same_bdseq() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    n.births()
    ddeath, ndeath = n.shutdown()
    assert ddeath.topic == "spBv1.0/G/DDEATH/E/m1" and pl.decode(ddeath.payload).seq == 2
    assert ndeath.topic == "spBv1.0/G/NDEATH/E" and ndeath.qos == 1 and not ndeath.retain
    p = pl.decode(ndeath.payload)
    assert not p.HasField("seq") and p.metrics[0].long_value == 3 and p.metrics[0].datatype == DataType.Int64


def test_invalid_ids_rejected() -> None:
    with pytest.raises(ValueError, match="without"):
        SparkplugNode("G/x", "E", AliasMap())
    with pytest.raises(ValueError, match="device id"):
        node().device_online("a+b", SPECS, [])


def state(online: bool, ts: int) -> bytes:
    return json.dumps({"online": online, "timestamp": ts}).encode()


def test_primary_host_timestamp_rules() -> None:
    host = PrimaryHost("H")
    t = "spBv1.0/STATE/H"
    assert host.on_state("spBv1.0/STATE/X", state(True, 1)) is StateVerdict.IGNORED
    assert host.on_state(t, b"ONLINE") is StateVerdict.IGNORED  # 2.2 style payload
    assert host.on_state(t, state(True, 100)) is StateVerdict.ONLINE and host.online
    assert host.on_state(t, state(False, 50)) is StateVerdict.IGNORED and host.online  # stale Will
    assert host.on_state(t, state(False, 100)) is StateVerdict.OFFLINE and not host.online  # >= is valid
    host.new_session()
    assert host.on_state(t, state(True, 99)) is StateVerdict.IGNORED  # the timestamp outlives the session
    assert host.on_state(t, state(True, 101)) is StateVerdict.ONLINE


def test_bdseq_persisted_wraps_and_reuses_an_unsent_attempt(tmp_path: Path) -> None:
    c = BdSeqCounter(StateStore(tmp_path))
    assert [c.next_for_connect() for _ in range(3)] == [0, 1, 2]
    assert c.next_for_connect(previous_unsent=True) == 2  # socket refused: CONNECT never left
    assert BdSeqCounter(StateStore(tmp_path)).next_for_connect() == 3  # restart continues
    (tmp_path / "sparkplug_bdseq.json").write_text('{"last": 255}')
    assert BdSeqCounter(StateStore(tmp_path)).next_for_connect() == 0
    (tmp_path / "sparkplug_bdseq.json").write_text("{torn")
    assert BdSeqCounter(StateStore(tmp_path)).next_for_connect() == 0  # corrupt file: start fresh, logged


def test_dbirths_after_the_nbirth_one_by_one_each_device_live_from_its_own() -> None:
    """The births in parts (the session sends the DBIRTHs over several loop turns): a device's DATA goes out
    only after its own DBIRTH (before it, the value is recorded and its DBIRTH carries it), a device going
    offline before its DBIRTH sends no DDEATH, and the seq runs on across the parts."""
    n = node()
    for device_id in ("m1", "m2", "m3"):
        n.device_online(device_id, SPECS, [])
    nbirth = n.nbirth()
    assert n.live and n.unborn_devices() == ["m1", "m2", "m3"]
    (m1,) = n.dbirth("m1")
    assert n.dbirth("m1") == [], "born once per NBIRTH"
    (data1,) = n.device_data("m1", [Sample("Macro/500", 1.0, MetricType.DOUBLE, 10)])
    assert n.is_live("m1") and not n.is_live("m2")
    assert n.device_data("m2", [Sample("Macro/500", 2.0, MetricType.DOUBLE, 11)]) == []
    assert n.historical_rows("m2", [["Macro/500", 2.0, None, 11, 192]]) == []
    assert n.device_offline("m3") == [], "no DDEATH for a device not born since the NBIRTH"
    assert n.unborn_devices() == ["m2"]
    (m2,) = n.dbirth("m2")
    assert {m.name: m for m in pl.decode(m2.payload).metrics}["Macro/500"].double_value == 2.0
    assert seqs([nbirth, m1, data1, m2]) == [0, 1, 2, 3]
    assert [m.topic for m in n.shutdown()] == ["spBv1.0/G/DDEATH/E/m1", "spBv1.0/G/DDEATH/E/m2",
                                                 "spBv1.0/G/NDEATH/E"]


def test_a_new_nbirth_makes_every_device_unborn_until_its_dbirth() -> None:
    n = node()
    n.device_online("m1", SPECS, [])
    n.births()
    assert n.is_live("m1")
    assert n.request_rebirth() and not n.is_live("m1")
    n.nbirth()
    assert not n.is_live("m1") and n.unborn_devices() == ["m1"]
    assert n.device_data("m1", [Sample("Macro/500", 1.0, MetricType.DOUBLE, 10)]) == []
    n.dbirth("m1")
    assert n.is_live("m1")
