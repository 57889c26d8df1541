"""The OPC UA server fed samples directly, driven by asyncua's client over real TCP (Sign&Encrypt).

What a client sees: the 40501 structure and the plain metric folder, types and units, the CNC time as
SourceTimestamp, status codes from quality, subscriptions, alarm conditions and history events, and
writes answered from the command layer's outcome. The daemon end to end (simulator, broker, real writes)
is tests/integration/test_opcua_daemon.py.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio

asyncua = pytest.importorskip("asyncua", reason="the opcua extra (asyncua) is not installed")

from asyncua import Client, ua  # noqa: E402
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256  # noqa: E402

from edge.opcua.output import OpcUaOutput  # noqa: E402
from edge.opcua.processor import GatewayProcessor  # noqa: E402
from edge.opcua.security import ensure_certificate  # noqa: E402
from edge.opcua.server import MetricWrite  # noqa: E402
from edge.opcua.settings import OpcUaSettings  # noqa: E402
from edge.opcua.writes import WriteOutcome  # noqa: E402
from edge.samples import MetricSpec, MetricType, Quality, Sample  # noqa: E402
from tests.helpers import async_wait_for, free_port  # noqa: E402

pytestmark = [pytest.mark.integration, pytest.mark.asyncio(loop_scope="module")]

NS_URI = "urn:focas-edge:machines"
CLIENT_URI = "urn:focas-edge:test-client"
USER, PASSWORD = "operator", "s3cret-pass"
SPECS = [
    MetricSpec("Device/Model", MetricType.STRING),
    MetricSpec("Device/Version", MetricType.STRING),
    MetricSpec("Device/MaxAxis", MetricType.INT16),
    MetricSpec("Status/Run", MetricType.STRING),
    MetricSpec("Status/Emergency", MetricType.BOOLEAN),
    MetricSpec("Axis/X/Absolute", MetricType.DOUBLE, "mm"),
    MetricSpec("Spindle/1/Speed", MetricType.DOUBLE, "rpm"),
    MetricSpec("Counters/Parts", MetricType.INT64),
    MetricSpec("Alarm/Status", MetricType.UINT32),
    MetricSpec("Alarm/Event", MetricType.STRING),
    MetricSpec("Alarm/History", MetricType.STRING),
    MetricSpec("Macro/500", MetricType.DOUBLE, writable=True),
    MetricSpec("Macro/501", MetricType.DOUBLE, writable=True),
    MetricSpec("Pmc/R100", MetricType.UINT8, writable=True),
]
CNC_MS = 1_700_000_000_123  # a CNC time well away from the gateway's clock


def birth(ms: int = CNC_MS) -> list[Sample]:
    values = {"Device/Model": "31i-B", "Device/Version": "G421.01", "Device/MaxAxis": 5, "Status/Run": "STOP",
              "Status/Emergency": False, "Axis/X/Absolute": 12.5, "Counters/Parts": 41, "Macro/500": 1.0,
              "Pmc/R100": 7}
    kinds = {spec.name: spec.type for spec in SPECS}
    return [Sample(name, value, kinds[name], ms) for name, value in values.items()]


class Writes:
    """The command layer's stand-in: records each request and answers the outcome a test set."""

    def __init__(self) -> None:
        self.requests: list[MetricWrite] = []
        self.outcome = WriteOutcome(True)
        self.release: asyncio.Event | None = None
        self.finished = 0

    async def __call__(self, request: MetricWrite) -> WriteOutcome:
        self.requests.append(request)
        if request.refusal is not None:
            return WriteOutcome(False, request.refusal[0], request.refusal[1])
        if self.release is not None:
            await self.release.wait()
        self.finished += 1
        return self.outcome


class Served:
    def __init__(self, output: OpcUaOutput, settings: OpcUaSettings, writes: Writes, client_pki: tuple[Path, Path]):
        self.output, self.settings, self.writes = output, settings, writes
        self.cert, self.key = client_pki

    @property
    def url(self) -> str:
        return f"opc.tcp://127.0.0.1:{self.settings.port}{self.settings.path}"

    async def client(self, user: str | None = USER, password: str | None = PASSWORD, secure: bool = True) -> Client:
        client = Client(self.url, timeout=10)
        client.application_uri = CLIENT_URI
        if user is not None:
            client.set_user(user)
            client.set_password(password or "")
        if secure:
            await client.set_security(SecurityPolicyBasic256Sha256, certificate=str(self.cert),
                                      private_key=str(self.key), mode=ua.MessageSecurityMode.SignAndEncrypt)
        await client.connect()
        return client


def settings_for(state_dir: Path, **changes: Any) -> OpcUaSettings:
    base: dict[str, Any] = {"state_dir": state_dir, "host": "127.0.0.1", "port": free_port(), "users": {USER: PASSWORD}}
    base.update(changes)
    return OpcUaSettings(**base)


@pytest.fixture(scope="module")
def client_pki(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    files = ensure_certificate(tmp_path_factory.mktemp("client-pki"), CLIENT_URI, "localhost")
    return files.certificate, files.private_key


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def served(tmp_path_factory: pytest.TempPathFactory, client_pki: tuple[Path, Path]) -> AsyncIterator[Served]:
    writes = Writes()
    settings = settings_for(tmp_path_factory.mktemp("opcua-state"))
    output = OpcUaOutput(settings, writes, writable=lambda device, names: frozenset(names) - {"Macro/501"})
    await output.start()
    await output.device_online("m1", SPECS, birth())
    await async_wait_for(lambda: output.pending == 0, message="the birth applied")
    try:
        yield Served(output, settings, writes, client_pki)
    finally:
        await output.stop()


async def node(client: Client, path: str) -> Any:
    ns = await client.get_namespace_index(NS_URI)
    return client.get_node(ua.NodeId(path, ns))


async def test_address_space_follows_40501_and_keeps_every_metric(served: Served) -> None:
    client = await served.client()
    try:
        machines = await client.nodes.objects.get_child(["2:Machines"])
        machine = await machines.get_child(["2:m1"])
        names = {(await child.read_browse_name()).Name for child in await machine.get_children()}
        assert {"Identification", "Monitoring", "Production", "Notification", "Metrics"} <= names
        ident = await machine.get_child(["2:Identification"])
        assert await (await ident.get_child(["2:SoftwareRevision"])).read_value() == "G421.01"
        assert await (await ident.get_child(["2:Manufacturer"])).read_value() == "FANUC"
        assert await (await ident.get_child(["2:MaxAxes"])).read_data_type_as_variant_type() == ua.VariantType.Int16
        mirror = await machine.get_child(["2:Monitoring", "2:Axes", "2:X", "2:Absolute"])
        plain = await machine.get_child(["2:Metrics", "2:Axis", "2:X", "2:Absolute"])
        assert await mirror.read_value() == await plain.read_value() == 12.5
        assert await plain.read_data_type_as_variant_type() == ua.VariantType.Double
        units = await (await plain.get_child(["0:EngineeringUnits"])).read_value()
        assert (units.DisplayName.Text, units.Description.Text) == ("mm", "millimetre")
        assert units.UnitId == int.from_bytes(b"MMT", "big")
        assert await (await machine.get_child(["2:Production", "2:PartCounters", "2:Parts"])).read_value() == 41
        types = {"Counters/Parts": ua.VariantType.Int64, "Status/Emergency": ua.VariantType.Boolean,
                 "Pmc/R100": ua.VariantType.Byte, "Alarm/Status": ua.VariantType.UInt32}
        for metric, vtype in types.items():
            assert await (await node(client, f"m1/Metrics/{metric}")).read_data_type_as_variant_type() == vtype
        writable = await (await node(client, "m1/Metrics/Macro/500")).read_attribute(ua.AttributeIds.AccessLevel)
        readonly = await (await node(client, "m1/Metrics/Macro/501")).read_attribute(ua.AttributeIds.AccessLevel)
        assert writable.Value.Value & ua.AccessLevel.CurrentWrite.mask
        assert not readonly.Value.Value & ua.AccessLevel.CurrentWrite.mask  # the policy does not cover it
    finally:
        await client.disconnect()


async def test_value_carries_cnc_time_gateway_time_and_quality(served: Served) -> None:
    client = await served.client()
    try:
        before = datetime.now(UTC)
        await served.output.device_data("m1", [Sample("Spindle/1/Speed", 6000.0, MetricType.DOUBLE, CNC_MS + 500),
                                               Sample("Counters/Parts", 42, MetricType.INT64, CNC_MS + 600,
                                                      Quality.STALE),
                                               Sample("Status/Run", None, MetricType.STRING, CNC_MS + 700,
                                                      Quality.BAD)])
        speed = await node(client, "m1/Metrics/Spindle/1/Speed")
        value = await async_wait_for(lambda: _good(speed), message="the new spindle speed")
        assert value.Value.Value == 6000.0
        assert value.SourceTimestamp == datetime.fromtimestamp((CNC_MS + 500) / 1000, UTC)
        assert before <= value.ServerTimestamp <= datetime.now(UTC)
        parts = await read(await node(client, "m1/Metrics/Counters/Parts"))
        assert parts.StatusCode.value == ua.StatusCodes.UncertainLastUsableValue and parts.Value.Value == 42
        run = await read(await node(client, "m1/Metrics/Status/Run"))
        assert run.StatusCode.is_bad() and run.Value.Value is None
    finally:
        await client.disconnect()


async def read(n: Any) -> ua.DataValue:
    """The node's DataValue whatever its status (asyncua's read_value raises on a Bad one)."""
    return await n.read_attribute(ua.AttributeIds.Value, None, False)


async def _good(n: Any) -> Any:
    value = await read(n)
    return value if value.StatusCode.is_good() and value.Value.Value is not None else None


async def test_subscription_gets_each_change_and_offline_reads_bad(served: Served) -> None:
    client = await served.client()
    seen: list[ua.DataValue] = []

    class Handler:
        def datachange_notification(self, _node: Any, _value: Any, data: Any) -> None:
            seen.append(data.monitored_item.Value)

    try:
        subscription = await client.create_subscription(20, Handler())
        target = await node(client, "m1/Monitoring/Axes/X/Absolute")
        await subscription.subscribe_data_change(target, queuesize=10)
        await async_wait_for(lambda: seen, message="the initial value")
        server = served.output.server.server
        assert server is not None and server.bserver is not None  # its Publish requests served first (processor)
        assert {type(connection.processor) for connection in server.bserver.clients} == {GatewayProcessor}
        for step in range(1, 4):
            await served.output.device_data("m1", [Sample("Axis/X/Absolute", 12.5 + step, MetricType.DOUBLE,
                                                          CNC_MS + 1000 * step)])
        await async_wait_for(lambda: len(seen) >= 4, message="three changes")
        assert [v.Value.Value for v in seen[-3:]] == [13.5, 14.5, 15.5]
        assert [v.SourceTimestamp for v in seen[-3:]] == [datetime.fromtimestamp((CNC_MS + 1000 * s) / 1000, UTC)
                                                          for s in (1, 2, 3)]
        await served.output.device_offline("m1")
        await async_wait_for(lambda: seen[-1].StatusCode.value == ua.StatusCodes.BadNoCommunication,
                             message="BadNoCommunication after the session dropped")
        await served.output.device_online("m1", SPECS, birth(CNC_MS + 5000))
        await async_wait_for(lambda: seen[-1].StatusCode.is_good() and seen[-1].Value.Value == 12.5,
                             message="the birth's value again")
    finally:
        await client.disconnect()


async def test_writes_answer_the_command_layers_outcome(served: Served) -> None:
    writes = served.writes
    client = await served.client()
    try:
        macro = await node(client, "m1/Metrics/Macro/500")
        await macro.write_value(ua.DataValue(ua.Variant(2.5, ua.VariantType.Double)))
        assert writes.requests[-1] == MetricWrite("m1", "Macro/500", 2.5, USER, macro.nodeid.to_string())
        cases = {"not_allowed": ua.StatusCodes.BadUserAccessDenied, "out_of_bounds": ua.StatusCodes.BadOutOfRange,
                 "timeout": ua.StatusCodes.BadTimeout, "unavailable": ua.StatusCodes.BadCommunicationError}
        for code, status in cases.items():
            writes.outcome = WriteOutcome(False, code, "refused")
            assert await _write_status(macro, ua.Variant(3.0, ua.VariantType.Double)) == status
        writes.outcome = WriteOutcome(True)
        count = len(writes.requests)
        # a Float to a Double node: refused as a type mismatch, and still handed over (to be audited)
        assert await _write_status(macro, ua.Variant(3.0, ua.VariantType.Float)) == ua.StatusCodes.BadTypeMismatch
        assert writes.requests[count].refusal is not None and writes.requests[count].refusal[0] == "wrong_type"
        pmc = await node(client, "m1/Metrics/Pmc/R100")
        assert await _write_status(pmc, ua.Variant("x", ua.VariantType.String)) == ua.StatusCodes.BadTypeMismatch
        manufacturer = await node(client, "m1/Identification/Manufacturer")
        assert await _write_status(manufacturer, ua.Variant("x", ua.VariantType.String)) == \
            ua.StatusCodes.BadNotWritable
    finally:
        await client.disconnect()


async def _write_status(n: Any, variant: ua.Variant) -> int:
    params = ua.WriteParameters()
    params.NodesToWrite = [ua.WriteValue(NodeId=n.nodeid, AttributeId=ua.AttributeIds.Value,
                                         Value=ua.DataValue(variant))]
    (status,) = await n.session.write(params)
    return int(status.value)


async def test_a_client_gone_mid_write_leaves_the_write_to_finish(served: Served) -> None:
    writes = served.writes
    writes.release = asyncio.Event()
    finished = writes.finished
    client = await served.client()
    macro = await node(client, "m1/Metrics/Macro/500")
    pending = asyncio.ensure_future(macro.write_value(ua.DataValue(ua.Variant(4.0, ua.VariantType.Double))))
    await async_wait_for(lambda: writes.requests and writes.requests[-1].value == 4.0, message="the write handed over")
    client.uaclient.protocol.transport.abort()  # the client goes away with the write in flight
    pending.cancel()
    writes.release.set()
    writes.release = None
    await async_wait_for(lambda: writes.finished == finished + 1, message="the write finished")
    again = await served.client()  # and the server still serves
    try:
        assert await (await node(again, "m1/Metrics/Axis/X/Absolute")).read_value() is not None
    finally:
        await again.disconnect()


async def test_alarm_conditions_and_history_events(served: Served) -> None:
    client = await served.client()
    conditions: list[Any] = []
    history: list[Any] = []

    class Handler:
        def event_notification(self, event: Any) -> None:
            (conditions if event.EventType == ua.NodeId(ua.ObjectIds.AlarmConditionType) else history).append(event)

    try:
        ns = await client.get_namespace_index(NS_URI)
        history_type = await client.nodes.base_event_type.get_child([f"{ns}:CncAlarmHistoryEventType"])
        subscription = await client.create_subscription(20, Handler())
        alarm_type = client.get_node(ua.ObjectIds.AlarmConditionType)
        await subscription.subscribe_events(client.nodes.server, [alarm_type, history_type])
        raised = ('{"event":"raised","type":2,"number":1001,"axis":0,"message":"SPINDLE OVERHEAT",'
                  f'"timestamp_ms":{CNC_MS}}}')
        entry = ('{"occurred":"2023-11-14T22:13:20Z","occurred_ms":1700000000000,"type":4,"number":10,'
                 '"axis":1,"message":"OVERTRAVEL +X"}')
        await served.output.device_events("m1", [Sample("Alarm/Event", raised, MetricType.STRING, CNC_MS),
                                                 Sample("Alarm/History", entry, MetricType.STRING, 1_700_000_000_000)])
        await async_wait_for(lambda: conditions and history, message="the condition and the history event")
        condition = conditions[-1]
        assert condition.Message.Text == "SPINDLE OVERHEAT" and condition.SourceName == "m1"
        assert condition.Time == datetime.fromtimestamp(CNC_MS / 1000, UTC)
        assert getattr(condition, "ActiveState/Id") is True and condition.Retain is True
        old = history[-1]
        assert (old.AlarmType, old.AlarmNumber, old.Axis, old.Message.Text) == (4, 10, 1, "OVERTRAVEL +X")
        assert old.Time == datetime.fromtimestamp(1_700_000_000, UTC)
        # ConditionRefresh replays the active condition
        count = len(conditions)
        await client.nodes.server.call_method(ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                                              ua.Variant(subscription.subscription_id, ua.VariantType.UInt32))
        await async_wait_for(lambda: len(conditions) > count, message="the refreshed condition")
        await served.output.device_events("m1", [Sample("Alarm/Event", raised.replace("raised", "cleared"),
                                                        MetricType.STRING, CNC_MS + 2000)])
        await async_wait_for(lambda: getattr(conditions[-1], "ActiveState/Id") is False, message="the clear")
        assert conditions[-1].Retain is False
    finally:
        await client.disconnect()


async def test_sessions_need_a_known_user(served: Served) -> None:
    for user, password in ((None, None), (USER, "wrong"), ("nobody", PASSWORD)):
        with pytest.raises(ua.UaStatusCodeError) as refused:
            await served.client(user, password)
        assert refused.value.code in (ua.StatusCodes.BadUserAccessDenied, ua.StatusCodes.BadIdentityTokenRejected)
    probe = Client(served.url, timeout=10)
    endpoints = await probe.connect_and_get_server_endpoints()
    assert {e.SecurityPolicyUri.rsplit("#", 1)[-1] for e in endpoints} == {"Basic256Sha256"}
    assert {e.SecurityMode for e in endpoints} == {ua.MessageSecurityMode.SignAndEncrypt}
    assert all(t.TokenType != ua.UserTokenType.Anonymous for e in endpoints for t in e.UserIdentityTokens)
    state = served.settings.state_dir / "opcua"
    assert (state / "server-key.pem").stat().st_mode & 0o077 == 0


async def test_threaded_with_anonymous_and_no_security_when_asked(tmp_path: Path) -> None:
    """The non-default choices: in its own thread, no security, anonymous allowed; and the certificate made
    on the first start is the one a later start uses."""
    settings = settings_for(tmp_path, threaded=True, security=("None",), allow_anonymous=True)
    output = OpcUaOutput(settings)
    await output.start()
    try:
        await output.device_online("m2", SPECS[:3], birth()[:3])
        client = Client(f"opc.tcp://127.0.0.1:{settings.port}{settings.path}", timeout=10)
        async with client:
            model = await node(client, "m2/Identification/Model")
            await async_wait_for(lambda: _good(model), message="the model")
            assert await model.read_value() == "31i-B"
    finally:
        await output.stop()
    assert not (tmp_path / "opcua").exists()  # no certificate for a None-only endpoint
    encrypted = settings_for(tmp_path)
    for _ in range(2):
        output = OpcUaOutput(encrypted)
        await output.start()
        await output.stop()
        stamp = (tmp_path / "opcua" / "server-cert.der").read_bytes()
        if _ == 0:
            first = stamp
    assert stamp == first

