"""The daemon's OPC UA server end to end: simulated CNC over TCP -> daemon -> real mosquitto and OPC UA clients.

The same scenario with two independent clients — asyncua's and node-opcua (npm, installed by
scripts/ensure-node-opcua.sh into .node/) — over Basic256Sha256 Sign&Encrypt with a user and password:
browse the machine, receive a change the simulator makes and compare its SourceTimestamp with the
simulator's clock (45 s ahead of the gateway's, so the gateway's own time cannot pass), write an
allowed macro and find it in the simulated CNC, write a refused one and get the Bad status and an audit
line, and be refused without a user. A third test leans on the server (10,000 monitored items, wrong
types, a client gone mid-call) while MQTT keeps publishing.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("asyncua", reason="the opcua extra (asyncua) is not installed")

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from edge.config import parse_config
from edge.opcua.security import ensure_certificate
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, Machine, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, port_open
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
NODE_MODULES = REPO / ".node" / "node_modules"
NODE_CLIENT = Path(__file__).with_name("opcua_node_client.js")
NS_URI = "urn:focas-edge:machines"
USER, PASSWORD = "scada", "correct horse battery"
CNC_AHEAD_S = 45.0  # the simulated CNC runs 45 s ahead (within max_skew_s: the gateway stamps CNC time)
TIMEOUTS = "timeouts: {request_s: 0.5, connect_s: 0.5, backoff_initial_s: 0.05, backoff_max_s: 0.2}"
POLL = "poll: {periods: {status: 0.25, macros: 0.25, pmc: 0.5}, part_count: false, macros: ['500-510']}"


class Gateway:
    def __init__(self, daemon: Daemon, sim: Machine, state_dir: Path, port: int, observer: Observer) -> None:
        self.daemon, self.sim, self.state_dir, self.port, self.observer = daemon, sim, state_dir, port, observer

    @property
    def url(self) -> str:
        return f"opc.tcp://127.0.0.1:{self.port}/focas-edge"

    def audit(self) -> list[dict[str, Any]]:
        path = self.state_dir / "write-audit.jsonl"
        return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []

    def cnc_now(self) -> datetime:
        return self.sim.state.clock_utc()

    def ddata(self) -> int:
        return len(self.observer.on("spBv1.0/plant/DDATA/gw/m1"))


@pytest.fixture
async def gateway(mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> AsyncIterator[Gateway]:
    password = tmp_path / "scada.password"
    password.write_text(PASSWORD + "\n")
    port = free_port()
    async with Fleet([MachineSpec(profile="30i", clock_offset=CNC_AHEAD_S)], base_port=0) as fleet:
        machines = f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, {TIMEOUTS}, {POLL}}}\n"
        extra = f"""
writes:
  enabled: true
  allow:
    - {{target: 'macro:500-509', min: -1000, max: 1000}}
opcua:
  enabled: true
  host: 127.0.0.1
  port: {port}
  users:
    - {{username: {USER}, password_file: {password}}}
"""
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines, extra)))
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            await async_wait_for(lambda: port_open("127.0.0.1", port), timeout=30, message="the OPC UA endpoint")
            yield Gateway(daemon, fleet[0], tmp_path, port, observer)
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0


async def secure_client(gateway: Gateway, user: str | None = USER, password: str = PASSWORD) -> Client:
    pki = ensure_certificate(gateway.state_dir / "client-pki", "urn:focas-edge:test-client", "localhost")
    client = Client(gateway.url, timeout=10)
    client.application_uri = "urn:focas-edge:test-client"
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    await client.set_security(SecurityPolicyBasic256Sha256, certificate=str(pki.certificate),
                              private_key=str(pki.private_key), mode=ua.MessageSecurityMode.SignAndEncrypt)
    await client.connect()
    return client


def stamp_macro_later(gateway: Gateway, value: float, delay_s: float = 0.3) -> Callable[[], datetime]:
    """Set macro 510 on the simulated CNC after `delay_s` (while a client listens); returns when it was set
    on the CNC's clock."""
    loop = asyncio.get_running_loop()
    when: list[datetime] = []

    def change() -> None:
        when.append(gateway.cnc_now())
        gateway.sim.state.write_macro(510, value, protocol="admin")

    loop.call_later(delay_s, change)
    return lambda: when[0]


def assert_cnc_time(source: datetime, changed_at: datetime, received_at: datetime) -> None:
    """The SourceTimestamp is the CNC's time of the read that saw the change (not the gateway's clock)."""
    assert changed_at.timestamp() - 1.0 <= source.timestamp() <= received_at.timestamp() + 0.5, \
        (source, changed_at, received_at)


async def test_asyncua_client_browses_reads_subscribes_and_writes(gateway: Gateway) -> None:
    client = await secure_client(gateway)
    try:
        ns = await client.get_namespace_index(NS_URI)
        machine = client.get_node(ua.NodeId("m1", ns))
        names = {(await child.read_browse_name()).Name for child in await machine.get_children()}
        assert {"Identification", "Monitoring", "Production", "Notification", "Metrics"} <= names
        assert await client.get_node(ua.NodeId("m1/Identification/Manufacturer", ns)).read_value() == "FANUC"

        seen: list[tuple[ua.DataValue, datetime]] = []

        class Handler:
            def datachange_notification(self, _node: Any, _value: Any, data: Any) -> None:
                seen.append((data.monitored_item.Value, gateway.cnc_now()))

        subscription = await client.create_subscription(50, Handler())
        await subscription.subscribe_data_change(client.get_node(ua.NodeId("m1/Metrics/Macro/510", ns)))
        changed_at = stamp_macro_later(gateway, 123.25)
        await async_wait_for(lambda: any(v.Value.Value == 123.25 for v, _ in seen), timeout=10,
                             message="the change of macro 510")
        value, received = next((v, at) for v, at in seen if v.Value.Value == 123.25)
        assert_cnc_time(value.SourceTimestamp, changed_at(), received)
        assert abs(value.ServerTimestamp.timestamp() - time.time()) < CNC_AHEAD_S / 2  # the gateway's clock

        allowed = client.get_node(ua.NodeId("m1/Metrics/Macro/505", ns))
        refused = client.get_node(ua.NodeId("m1/Metrics/Macro/510", ns))
        writable = ua.AccessLevel.CurrentWrite.mask
        assert (await allowed.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value & writable  # the policy's
        assert not (await refused.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value & writable
        await allowed.write_value(ua.DataValue(ua.Variant(77.5, ua.VariantType.Double)))
        assert gateway.sim.state.read_macro(505) == 77.5
        with pytest.raises(ua.uaerrors.BadUserAccessDenied):
            await refused.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
        with pytest.raises(ua.uaerrors.BadOutOfRange):
            await allowed.write_value(ua.DataValue(ua.Variant(5000.0, ua.VariantType.Double)))
        assert gateway.sim.state.read_macro(510) == 123.25 and gateway.sim.state.read_macro(505) == 77.5
        audit = gateway.audit()
        assert [(a["target"], a["outcome"], a["source"], a["client_id"]) for a in audit] == [
            ("macro:505", "ok", "opcua", USER), ("macro:510", "not_allowed", "opcua", USER),
            ("macro:505", "out_of_bounds", "opcua", USER)]
        assert audit[0]["topic"] == f"ns={ns};s=m1/Metrics/Macro/505" and audit[0]["new"] == 77.5
    finally:
        await client.disconnect()
    with pytest.raises(ua.UaStatusCodeError):
        await secure_client(gateway, user=None)


def node_client_or_skip() -> list[str]:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (apt-get install nodejs npm); the node-opcua interop test needs it")
    if not (NODE_MODULES / "node-opcua" / "package.json").is_file():
        pytest.skip(f"node-opcua is not installed in {NODE_MODULES} (make test runs scripts/ensure-node-opcua.sh; "
                    "it needs npm and the npm registry)")
    return [node, str(NODE_CLIENT)]


async def test_node_opcua_client_browses_reads_subscribes_and_writes(gateway: Gateway, tmp_path: Path) -> None:
    command = node_client_or_skip()
    scenario = {"url": gateway.url, "user": USER, "password": PASSWORD, "namespaceUri": NS_URI, "machine": "m1",
                "read": "m1/Identification/Manufacturer", "subscribe": "m1/Metrics/Macro/510", "changes": 2,
                "pki": str(tmp_path / "node-pki"),
                "writes": [{"node": "m1/Metrics/Macro/506", "value": -12.5, "dataType": "Double"},
                           {"node": "m1/Metrics/Macro/510", "value": 2.0, "dataType": "Double"},
                           {"node": "m1/Metrics/Macro/506", "value": "x", "dataType": "String"}]}
    process = await asyncio.create_subprocess_exec(
        *command, json.dumps(scenario), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        env={**os.environ, "NODE_PATH": str(NODE_MODULES)})
    # the first notification is the current value; the second is the change the simulator makes
    changed_at = stamp_macro_later(gateway, 321.5, delay_s=3.0)
    stdout, stderr = await asyncio.wait_for(process.communicate(), 90)
    received = gateway.cnc_now()
    lines = stdout.decode().strip().splitlines()
    result = json.loads(lines[-1]) if lines else {"error": stderr.decode()[-2000:]}
    assert "error" not in result, result["error"]
    assert {"Identification", "Monitoring", "Production", "Notification", "Metrics"} <= set(result["components"])
    assert "Macro" in result["metricFolders"]
    assert result["read"]["value"] == "FANUC" and result["read"]["status"] == "Good"
    change = result["changes"][-1]
    assert change["value"] == 321.5 and change["dataType"] == "Double" and change["status"] == "Good"
    assert_cnc_time(datetime.fromtimestamp(change["sourceTimestamp"] / 1000, UTC), changed_at(), received)
    assert [w["status"] for w in result["writes"]] == ["Good", "BadUserAccessDenied", "BadTypeMismatch"]
    assert gateway.sim.state.read_macro(506) == -12.5 and gateway.sim.state.read_macro(510) == 321.5
    outcomes = [(a["target"], a["outcome"]) for a in gateway.audit()]
    assert outcomes == [("macro:506", "ok"), ("macro:510", "not_allowed"), ("Macro/506", "wrong_type")]
    assert result["anonymous"]["refused"] is True


async def test_a_heavy_or_rude_client_does_not_disturb_polling_or_mqtt(gateway: Gateway) -> None:
    """10,000 monitored items, three wrong-type writes and a connection dropped mid-session, from a client in
    its own process: the data keeps flowing to MQTT, the daemon stays healthy, nothing reaches the CNC."""
    pki = ensure_certificate(gateway.state_dir / "client-pki", "urn:focas-edge:test-client", "localhost")
    before = gateway.ddata()
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tests.integration.opcua_rude_client", gateway.url, USER, PASSWORD,
        str(pki.certificate), str(pki.private_key), stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    stdout, stderr = await asyncio.wait_for(process.communicate(), 120)
    assert process.returncode == 0, stderr.decode()[-2000:]
    result = json.loads(stdout.decode().strip().splitlines()[-1])
    assert result == {"items": 10_000, "writes": ["BadTypeMismatch"] * 3}
    await async_wait_for(lambda: gateway.ddata() >= before + 20, timeout=15, message="DDATA flowing meanwhile")
    assert gateway.daemon.healthy()
    assert [a["outcome"] for a in gateway.audit()] == ["wrong_type"] * 3
    again = await secure_client(gateway)
    try:
        ns = await again.get_namespace_index(NS_URI)
        assert await again.get_node(ua.NodeId("m1/Identification/Manufacturer", ns)).read_value() == "FANUC"
    finally:
        await again.disconnect()
    assert gateway.sim.state.writes("macro:") == []  # nothing wrong reached the CNC
