"""Who may write is decided at the broker: a real mosquitto with the ACL `focas-edge init --acl` writes
(edge.service.broker_acl) and a password file. A client without the right can neither cause a write on the
simulated CNC nor publish as the gateway; the MES account's write goes through.

Negative checks without sleeping: the intruder's publishes are PUBACKed (the broker has handled them) before
the MES sends its own command; had the broker forwarded them, the gateway and the MES's subscriber would
have received them first. So once the MES's reply is in, anything forwarded would have been seen.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.publish.sparkplug_b_pb2 import Payload
from edge.service.broker_acl import render_acl
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, mosquitto_binary
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

FORGED = -12345.678
PASSWORDS = {"edge": "gw-secret", "mes": "mes-secret", "intruder": "intruder-secret"}
WRITES = """
writes:
  enabled: true
  rate_limit: {max_writes: 100, per_s: 60}
  allow: [{target: 'macro:500-509'}]
"""


def gateway_config(broker: Mosquitto, state_dir: Path, port: int, password_file: Path) -> str:
    machines = (f"  - {{id: m1, host: 127.0.0.1, port: {port}, timeouts: {{request_s: 0.5, connect_s: 0.5}}, "
                "poll: {periods: {status: 0.25, macros: 0.5}, part_count: false, macros: ['500-509']}}\n")
    text = daemon_config(broker, state_dir, machines, WRITES)
    return text.replace(f"  port: {broker.port}\n",
                        f"  port: {broker.port}\n  username: edge\n  password_file: {password_file}\n")


@pytest.fixture
def acl_broker(tmp_path: Path) -> Iterator[Mosquitto]:
    """mosquitto with a password file and, once the test wrote it, the gateway's ACL (tmp_path/acl)."""
    binary = mosquitto_binary()
    if binary is None:
        pytest.skip("mosquitto is not installed")
    passwd = tmp_path / "passwd"
    passwd.write_text("")
    for user, password in PASSWORDS.items():
        subprocess.run(["mosquitto_passwd", "-b", str(passwd), user, password], check=True, capture_output=True)
    broker = Mosquitto(binary)
    # As root, mosquitto drops to user "mosquitto", which cannot read files under pytest's 0700 tmp dirs.
    user = "user root\n" if os.geteuid() == 0 else ""
    broker.conf.write_text(f"listener {broker.port} 127.0.0.1\npersistence false\nlog_dest stderr\n{user}"
                           f"allow_anonymous false\npassword_file {passwd}\nacl_file {tmp_path / 'acl'}\n")
    try:
        yield broker
    finally:
        broker.close()


async def test_only_the_mes_may_write_and_only_the_gateway_may_speak_as_the_gateway(
        acl_broker: Mosquitto, tmp_path: Path) -> None:
    broker = acl_broker
    secret = tmp_path / "edge-password"
    secret.write_text(PASSWORDS["edge"])
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        text = gateway_config(broker, tmp_path / "state", fleet[0].port, secret)
        config = parse_config(text)
        (tmp_path / "acl").write_text(render_acl(config, "edge", "mes"))
        broker.start()
        mes = Observer(broker, username="mes", password=PASSWORDS["mes"])
        intruder = Observer(broker, username="intruder", password=PASSWORDS["intruder"])
        daemon = Daemon(config)
        task = asyncio.create_task(daemon.run())
        try:
            await mes.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            births = len(mes.on("spBv1.0/plant/DBIRTH/gw/m1"))

            # The intruder tries to write (JSON and DCMD) and to speak as the gateway; the MES tries the latter.
            await intruder.publish("focas/m1/cmd", json.dumps({"id": "x", "target": "macro:500", "value": 66}).encode())
            dcmd = Payload(metrics=[Payload.Metric(name="Macro/501", double_value=66.0)]).SerializeToString()
            await intruder.publish("spBv1.0/plant/DCMD/gw/m1", dcmd)
            forged = Payload(metrics=[Payload.Metric(name="Macro/500", double_value=FORGED)]).SerializeToString()
            for client in (intruder, mes):
                await client.publish("spBv1.0/plant/DDATA/gw/m1", forged)
                await client.publish("spBv1.0/plant/DBIRTH/gw/m1", forged)
                await client.publish("focas/m1/state/Macro/500", json.dumps({"value": FORGED}).encode())
                await client.publish("focas/m1/cmd/reply", b'{"id": "forged", "ok": true}')
            # The MES account's write goes through.
            await mes.publish("focas/m1/cmd", json.dumps({"id": "mes", "target": "macro:502", "value": 7}).encode())
            await mes.wait_topic("focas/m1/cmd/reply", timeout=15)

            (reply,) = [json.loads(m.payload) for m in mes.on("focas/m1/cmd/reply")]
            assert reply["id"] == "mes" and reply["ok"] is True, reply
            assert [(w.target, w.new) for w in fleet[0].state.writes("macro:")] == [("macro:502", 7.0)]
            audit = [json.loads(line) for line in (tmp_path / "state" / "write-audit.jsonl").read_text().splitlines()]
            assert [a["request_id"] for a in audit] == ["mes"], "the intruder's commands never reached the gateway"
            # The MES's subscriber never saw a forged message on the gateway's topics.
            assert all(json.loads(m.payload)["value"] != FORGED for m in mes.on("focas/m1/state/Macro/500"))
            assert len(mes.on("spBv1.0/plant/DBIRTH/gw/m1")) == births, "no forged DBIRTH"
            assert all(metric.double_value != FORGED for m in mes.on("spBv1.0/plant/DDATA/gw/m1")
                       for metric in m.spb().metrics)
            # Nor does the intruder read what the gateway publishes (nothing is granted to it).
            assert intruder.snapshot() == []
        finally:
            mes.close()
            intruder.close()
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0
