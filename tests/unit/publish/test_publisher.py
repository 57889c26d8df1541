"""Fuzz the publisher's inbound command paths: Sparkplug NCMD/DCMD and the JSON cmd topic dispatch. Nothing
raises, and nothing reaches the write handler (the only way to a CNC) unless it is a declared, writable
metric with a value of its declared type. (The JSON write-request parser is fuzzed in
tests/unit/command/test_requests.py.)
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from edge.command.errors import ErrorCode
from edge.publish import CommandSource, DeviceCommands, Publisher
from edge.publish.mqtt import InboundMessage
from edge.publish.settings import PublishSettings
from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.samples import MetricSpec, MetricType

SPECS = [
    MetricSpec("Macro/500", MetricType.DOUBLE, writable=True),
    MetricSpec("PMC/R100", MetricType.UINT8, writable=True),
    MetricSpec("Status/Run", MetricType.INT16),
]
WRITABLE = {s.name: s for s in SPECS if s.writable}
NCMD = "spBv1.0/plant/NCMD/gw"
DCMD = "spBv1.0/plant/DCMD/gw/m1"
REFUSED: list[tuple[Any, ...]] = []  # DCMD metrics the publisher refused in the last run_messages
DCMDS: list[DeviceCommands] = []  # what the handler was handed, one per DCMD message


def run_messages(tmp: Path, messages: list[InboundMessage], fmt: str) -> tuple[list[tuple[Any, ...]], Publisher]:
    """Feed inbound messages to a publisher (not connected) with a declared device; the handler calls."""
    calls: list[tuple[Any, ...]] = []
    REFUSED.clear()
    DCMDS.clear()

    async def body() -> Publisher:
        settings = PublishSettings(state_dir=tmp, group_id="plant", edge_node_id="gw", json_prefix="focas")
        pub = Publisher(settings)

        async def device_command(commands: DeviceCommands, source: CommandSource) -> None:
            DCMDS.append(commands)
            calls.extend((commands.device_id, name, value) for name, value in commands.writes)
            REFUSED.extend((commands.device_id, r.metric, r.code, r.reason) for r in commands.refused)

        async def json_command(machine: str, payload: bytes, source: CommandSource) -> None:
            calls.append((machine, payload))

        pub.on_device_command = device_command
        pub.on_json_command = json_command
        await pub.device_online("m1", SPECS, [])
        for msg in messages:
            (pub._spb.handle_message if fmt == "sparkplug" else pub._json.handle_message)(msg)
        await asyncio.sleep(0)
        await pub.stop()
        return pub

    pub = asyncio.run(body())
    return calls, pub


metric_names = st.one_of(st.sampled_from([s.name for s in SPECS] + ["Node Control/Rebirth", "bdSeq"]),
                         st.text(max_size=20))
values = st.one_of(
    st.fixed_dictionaries({"int_value": st.integers(0, 2**32 - 1)}),
    st.fixed_dictionaries({"long_value": st.integers(0, 2**64 - 1)}),
    st.fixed_dictionaries({"double_value": st.floats()}),
    st.fixed_dictionaries({"float_value": st.floats(width=32)}),
    st.fixed_dictionaries({"boolean_value": st.booleans()}),
    st.fixed_dictionaries({"string_value": st.text(max_size=10)}),
    st.just({"is_null": True}),
    st.just({}),
)
metrics = st.tuples(st.one_of(st.none(), metric_names), st.one_of(st.none(), st.integers(0, 2**64 - 1)),
                    st.one_of(st.none(), st.sampled_from(list(DataType.values()))), values)


def payload_of(ms: list[tuple[Any, ...]]) -> bytes:
    p = Payload(timestamp=1)
    for name, alias, datatype, value in ms:
        m = p.metrics.add(**value)
        if name is not None:
            m.name = name
        if alias is not None:
            m.alias = alias
        if datatype is not None:
            m.datatype = datatype
    return p.SerializeToString()


def assert_only_valid_writes(calls: list[tuple[Any, ...]]) -> None:
    for device, name, value in calls:
        assert device == "m1" and name in WRITABLE, (device, name)
        if WRITABLE[name].type is MetricType.DOUBLE:
            assert value is None or isinstance(value, float)
        else:
            assert value is None or (isinstance(value, int) and 0 <= value <= 255), value


@given(st.lists(metrics, max_size=6), st.sampled_from([NCMD, DCMD, "spBv1.0/plant/DCMD/gw/m9",
                                                         "spBv1.0/other/DCMD/gw/m1", "spBv1.0/plant/DCMD/gw"]))
def test_fuzz_structured_sparkplug_commands_reach_the_handler_only_when_valid(
        tmp_path_factory: Any, ms: list[tuple[Any, ...]], topic: str) -> None:
    calls, _ = run_messages(tmp_path_factory.mktemp("p"), [InboundMessage(topic, payload_of(ms), False)],
                              "sparkplug")
    assert_only_valid_writes(calls)
    if topic != DCMD:
        assert not calls
    assert len(calls) <= len(ms)
    # Every DCMD metric for this node is either a write or an audited refusal with a reply code.
    codes = {code.value for code in ErrorCode}
    assert all(code in codes and reason for _, _, code, reason in REFUSED), REFUSED
    if topic in (DCMD, "spBv1.0/plant/DCMD/gw/m9"):
        assert len(calls) + len(REFUSED) == max(len(ms), 1)  # a DCMD without metrics is refused too
        # One DCMD is one hand-off (the command layer caps and audits it as one command), with its size.
        assert len(DCMDS) == 1
        assert all(d.payload_bytes == len(payload_of(ms)) for d in DCMDS)
    else:
        assert not REFUSED


@given(st.binary(max_size=200), st.sampled_from([NCMD, DCMD]))
def test_fuzz_arbitrary_bytes_as_sparkplug_commands(tmp_path_factory: Any, data: bytes, topic: str) -> None:
    calls, pub = run_messages(tmp_path_factory.mktemp("p"), [InboundMessage(topic, data, False)], "sparkplug")
    assert_only_valid_writes(calls)
    assert pub.counters["rebirth_requests"] <= 1 + data.count(b"\x01")


@given(st.text(max_size=40), st.binary(max_size=100))
def test_fuzz_json_command_topics_dispatch_only_machine_cmd_topics(tmp_path_factory: Any, topic: str,
                                                                   data: bytes) -> None:
    calls, _ = run_messages(tmp_path_factory.mktemp("p"), [InboundMessage(topic, data, False)], "json")
    for machine, payload in calls:
        assert topic == f"focas/{machine}/cmd" and "/" not in machine and machine
        assert payload == data


def test_the_harness_does_deliver_a_valid_dcmd(tmp_path: Path) -> None:
    """Guards the fuzz tests above against passing because nothing ever reaches the handler."""
    good = payload_of([("Macro/500", None, DataType.Double, {"double_value": 1.5}),
                       ("Status/Run", None, DataType.Int16, {"int_value": 1}),
                       ("PMC/R100", None, DataType.UInt8, {"int_value": 256})])
    calls, _ = run_messages(tmp_path, [InboundMessage(DCMD, good, False)], "sparkplug")
    assert calls == [("m1", "Macro/500", 1.5)]
    calls, _ = run_messages(tmp_path, [InboundMessage("focas/m1/cmd", b"{}", False)], "json")
    assert calls == [("m1", b"{}")]
