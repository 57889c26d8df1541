"""The optional /healthz and /metrics endpoint of a running daemon (simulator + real mosquitto)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, port_open

pytestmark = pytest.mark.integration


async def http_get(port: int, path: str, method: str = "GET") -> tuple[int, dict[str, str], bytes]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(f"{method} {path} HTTP/1.1\r\nHost: localhost\r\n\r\n".encode())
        await writer.drain()
        raw = await asyncio.wait_for(reader.read(), 5)  # Connection: close -> read to EOF
    finally:
        writer.close()
    head, _, body = raw.partition(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    status = int(lines[0].split()[1])
    headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    return status, headers, body


def config_text(broker: Mosquitto, state_dir: Path, ports: list[int], http_port: int, share: float) -> str:
    machines = "".join(
        f"  - {{id: m{i + 1}, host: 127.0.0.1, port: {port}, "
        f"timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.3}}}}\n"
        for i, port in enumerate(ports))
    return f"""
mqtt:
  host: {broker.host}
  port: {broker.port}
  formats: [sparkplug, json]
  sparkplug: {{group_id: plant, edge_node_id: gw}}
state_dir: {state_dir}
http: {{enabled: true, host: 127.0.0.1, port: {http_port}, healthy_share: {share}}}
machines:
{machines}
"""


def samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            out[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return out


async def test_healthz_and_metrics_follow_the_live_state(mosquitto: Mosquitto, tmp_path: Path) -> None:
    http_port = free_port()
    async with Fleet([MachineSpec(profile="30i", clock_offset=5.0), MachineSpec(profile="16i")],
                     base_port=0) as fleet:
        fleet[1].faults.update({"ew": {"read_macros": 6}})
        text = config_text(mosquitto, tmp_path, [fleet[0].port, fleet[1].port], http_port, 0.75)
        text = text.replace("port: " + str(fleet[1].port) + ",",
                            "port: " + str(fleet[1].port) + ", poll: {macros: ['500-501']},")
        daemon = Daemon(parse_config(text))
        task = asyncio.create_task(daemon.run())
        try:
            await async_wait_for(lambda: port_open("127.0.0.1", http_port), 10, message="status endpoint")
            status, _, body = await http_get(http_port, "/healthz")
            assert status in (200, 503)  # it answers from the start, whatever the state
            await async_wait_for(lambda: all(p.online for p in daemon.pollers.values()) and
                                 all(p.stats.ticks > 3 for p in daemon.pollers.values()), 15,
                                 message="both machines polling")
            status, headers, body = await http_get(http_port, "/healthz")
            assert status == 200, body
            assert headers["content-type"] == "application/json"
            assert json.loads(body)["status"] == "ok"

            status, headers, body = await http_get(http_port, "/metrics")
            assert status == 200 and headers["content-type"].startswith("text/plain")
            got = samples(body.decode())
            assert got[("focas_edge_machine_connected", (("machine", "m1"),))] == 1
            assert got[("focas_edge_broker_connected", ())] == 1
            assert got[("focas_edge_spool_depth", ())] == 0
            assert got[("focas_edge_poll_cycle_seconds_count", (("machine", "m1"),))] >= 3
            assert got[("focas_edge_poll_cycle_seconds_bucket", (("le", "+Inf"), ("machine", "m1")))] == \
                got[("focas_edge_poll_cycle_seconds_count", (("machine", "m1"),))]
            assert got[("focas_edge_cnc_errors_total",
                        (("code", "EW_NOOPT"), ("function", "ReadMacros"), ("machine", "m2")))] >= 1
            assert 4.0 < got[("focas_edge_clock_skew_seconds", (("machine", "m1"),))] < 6.0
            assert got[("focas_edge_mqtt_messages_total", (("outcome", "published"),))] > 0
            assert ("focas_edge_poll_overruns_total", (("machine", "m2"),)) in got

            # One of two machines down: 50 % < 75 % -> 503 naming the machine.
            fleet[1].faults.update({"refuse": -1})
            fleet[1].drop_connections()
            await async_wait_for(lambda: not daemon.pollers["m2"].online, 10, message="m2 offline")
            status, _, body = await http_get(http_port, "/healthz")
            doc = json.loads(body)
            assert status == 503 and doc["machines_connected"] == 1 and "m2" in doc["reasons"][0], doc
            got = samples((await http_get(http_port, "/metrics"))[2].decode())
            assert got[("focas_edge_machine_connected", (("machine", "m2"),))] == 0
            fleet[1].faults.clear()
            await async_wait_for(lambda: daemon.pollers["m2"].online, 10, message="m2 back")
            assert (await http_get(http_port, "/healthz"))[0] == 200

            # Broker away -> 503 with the broker reason.
            mosquitto.stop()
            await async_wait_for(lambda: not daemon.publisher.connected, 10, message="broker loss seen")
            status, _, body = await http_get(http_port, "/healthz")
            assert status == 503 and "broker" in json.loads(body)["reasons"][0]
            # Rows wait in the spool: the depth says how many, as a gauge (it goes down on replay).
            await async_wait_for(lambda: daemon.spool.pending() > 3, 10, message="rows spooled")
            text = (await http_get(http_port, "/metrics"))[2].decode()
            families = {f.name: f for f in text_string_to_metric_families(text)}
            assert families["focas_edge_spool_depth"].type == "gauge"
            depth = samples(text)[("focas_edge_spool_depth", ())]
            assert 3 < depth <= daemon.spool.pending(), depth
            events = families["focas_edge_publisher_events"]
            assert not [s for s in events.samples if s.labels["event"] in ("spool_rows", "unconfirmed_batches")]
            assert families["focas_edge_unconfirmed_batches"].type == "gauge"

            assert (await http_get(http_port, "/nope"))[0] == 404
            assert (await http_get(http_port, "/healthz", "POST"))[0] == 405
            status, headers, body = await http_get(http_port, "/metrics", "HEAD")
            assert status == 200 and body == b"" and int(headers["content-length"]) > 0
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    assert not port_open("127.0.0.1", http_port), "the endpoint stops with the daemon"


async def test_endpoint_is_off_by_default(mosquitto: Mosquitto, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        text = config_text(mosquitto, tmp_path, [fleet[0].port], 9108, 0.5).replace(
            "http: {enabled: true, host: 127.0.0.1, port: 9108, healthy_share: 0.5}\n", "")
        daemon = Daemon(parse_config(text))
        task = asyncio.create_task(daemon.run())
        try:
            await async_wait_for(lambda: daemon.pollers and all(p.online for p in daemon.pollers.values()), 10,
                                 message="polling")
            assert daemon.status_http is None
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
