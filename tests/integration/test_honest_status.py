"""Honest data (issue 24 points 2, 3): a dead machine never looks alive, broker trouble is said and shown.

A daemon on the test's loop polls a simulated CNC over TCP and publishes to a real mosquitto:
- the CNC's session drops (and reconnects are refused): status.json says STALE with the values' age, a late
  JSON subscriber reads STALE from the retained state topics, and the page in headless Chromium greys
  them; when the CNC answers again, GOOD values replace them;
- the broker refuses connections: one WARNING per connection naming host:port and the reason (not one line
  per attempt), status.json and systemd's STATUS= say the broker is down with the last error; when the
  broker is back, one line says how long it was down.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import socket
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.service.sdnotify import SystemdNotifier
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, mosquitto_binary, port_open
from tests.integration.mqtt_observer import Observer
from tests.integration.test_status_http import config_text, http_get
from tests.integration.test_status_page import SCREENSHOT, chromium, run_browser

pytestmark = pytest.mark.integration

STATE = "focas/plant/gw/m1/state/"  # config_text names no prefix: the default names the gateway


async def status_json(http_port: int) -> dict[str, Any]:
    return json.loads((await http_get(http_port, "/status.json"))[2])


@asynccontextmanager
async def running_daemon(daemon: Daemon, http_port: int) -> AsyncIterator[Daemon]:
    task = asyncio.create_task(daemon.run())
    try:
        await async_wait_for(lambda: port_open("127.0.0.1", http_port), 10, message="status endpoint")
        yield daemon
    finally:
        daemon.request_stop()
        await asyncio.wait_for(task, 20)


@asynccontextmanager
async def one_machine(broker: Mosquitto, tmp_path: Path, **daemon_args: Any) -> AsyncIterator[tuple[Fleet, int,
                                                                                                     Daemon]]:
    """One simulated 30i polled at 4 Hz by a daemon with its status endpoint on; yields (fleet, port, daemon)."""
    http_port = free_port()
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        config_file = tmp_path / "focas-edge.yaml"
        config_file.write_text(config_text(broker, tmp_path / "state", [fleet[0].port], http_port, 0.5))
        (tmp_path / "state").mkdir()
        daemon = Daemon(parse_config(config_file.read_text()), config_file, **daemon_args)
        async with running_daemon(daemon, http_port):
            yield fleet, http_port, daemon


def qualities(messages: list[Any]) -> dict[str, str]:
    """The last quality seen on each state topic."""
    return {m.topic: json.loads(m.payload)["quality"] for m in messages if m.topic.startswith(STATE)}


async def machine_stale(http_port: int) -> bool:
    machine = (await status_json(http_port))["machines"][0]
    return (not machine["connected"] and bool(machine["values"])
            and all(v["quality"] == "STALE" and v["age_s"] >= 1.0 for v in machine["values"]))


async def machine_good(http_port: int) -> bool:
    machine = (await status_json(http_port))["machines"][0]
    return machine["connected"] and bool(machine["values"]) and all(v["quality"] == "GOOD"
                                                                     for v in machine["values"])


async def drop_session(fleet: Fleet, daemon: Daemon) -> None:
    """The CNC cuts the session and refuses every reconnect until told otherwise."""
    poller = daemon.pollers["m1"]
    await async_wait_for(lambda: poller.online and poller.stats.ticks > 3, 20, message="m1 polling")
    fleet[0].faults.refuse = -1
    fleet[0].drop_connections()
    await async_wait_for(lambda: not poller.online, 15, message="m1's session noticed lost")


async def test_a_dropped_session_is_stale_in_status_json_and_to_a_late_json_subscriber(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with one_machine(mosquitto, tmp_path) as (fleet, http_port, daemon):
        await async_wait_for(lambda: machine_good(http_port), 20, interval=0.1, message="m1's values GOOD")
        machine = (await status_json(http_port))["machines"][0]
        assert all(0 <= v["age_s"] < 3 and v["last_good"] for v in machine["values"]), machine["values"]
        await async_wait_for(lambda: qualities(observer.snapshot()), 10, message="m1's retained state")
        topics = set(qualities(observer.snapshot()))

        await drop_session(fleet, daemon)
        await async_wait_for(lambda: machine_stale(http_port), 15, interval=0.1, message="status.json STALE")
        values = (await status_json(http_port))["machines"][0]["values"]
        assert all(re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d", v["last_good"]) for v in values)
        # Every state topic restated STALE on the broker; a subscriber arriving now reads only STALE.
        await async_wait_for(lambda: set(qualities(observer.snapshot()).values()) == {"STALE"}, 10,
                             message="every state topic restated STALE")
        late = Observer(mosquitto, (f"{STATE}#",))
        try:
            # At least m1's topics of this run (the suite's broker may hold retained ones of earlier tests too)
            await async_wait_for(lambda: topics <= set(qualities(late.snapshot())), 10, message="retained state")
            retained = [m for m in late.snapshot() if m.retain and m.topic in topics]
            assert retained and {json.loads(m.payload)["quality"] for m in retained} == {"STALE"}
            assert all("stale_since" in json.loads(m.payload) for m in retained)
        finally:
            late.close()

        fleet[0].faults.refuse = 0  # the CNC answers again: fresh GOOD values replace the stale ones
        await async_wait_for(lambda: machine_good(http_port), 20, interval=0.1, message="status.json GOOD again")
        again = Observer(mosquitto, (f"{STATE}Status/#",))
        try:
            await async_wait_for(lambda: qualities(again.snapshot()), 10, message="retained status values")
            assert set(qualities(again.snapshot()).values()) == {"GOOD"}
        finally:
            again.close()


async def test_after_a_clean_stop_a_late_json_subscriber_reads_stale(mosquitto: Mosquitto, observer: Observer,
                                                                      tmp_path: Path) -> None:
    async with one_machine(mosquitto, tmp_path) as (_, http_port, __):
        await async_wait_for(lambda: machine_good(http_port), 20, interval=0.1, message="m1's values GOOD")
        await async_wait_for(lambda: qualities(observer.snapshot()), 10, message="m1's retained state")
    topics = set(qualities(observer.snapshot()))
    late = Observer(mosquitto, (f"{STATE}#",))
    try:
        await async_wait_for(lambda: topics <= set(qualities(late.snapshot())), 10, message="retained state")
        assert {quality for topic, quality in qualities(late.snapshot()).items() if topic in topics} == {"STALE"}
    finally:
        late.close()


async def test_the_page_greys_a_stale_value_and_shows_the_gateway(mosquitto: Mosquitto, tmp_path: Path) -> None:
    binary = chromium()
    if binary is None:
        pytest.skip("no chromium: `make test` installs it (scripts/ensure-chromium.sh)")
    async with one_machine(mosquitto, tmp_path) as (fleet, http_port, daemon):
        await drop_session(fleet, daemon)
        await async_wait_for(lambda: machine_stale(http_port), 15, interval=0.1, message="status.json STALE")
        dom = await run_browser(binary, f"http://127.0.0.1:{http_port}/", "--dump-dom")
        updates = re.search(r'data-updates="(\d+)"', dom)
        assert updates and int(updates.group(1)) >= 2, dom[:2000]  # drawn by the script, not only the server
        row = re.search(r'<tr id="machine-m1">(.*?)</tr>', dom, re.S)
        assert row is not None, dom[:2000]
        stale = re.findall(r'<div class="stale">(.*?)</div>', row.group(1))
        assert stale and any(line.startswith("Status/Run = ") for line in stale), row.group(1)
        assert all(re.search(r"\[STALE since \d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d, \d+ s ago\]", line)
                   for line in stale), stale
        assert '<dd id="gw-edge_node_id">plant/gw</dd>' in dom
        assert f'<dd id="gw-config_file">{tmp_path / "focas-edge.yaml"}</dd>' in dom
        assert f'<dd id="gw-host_name">{socket.gethostname()}</dd>' in dom
        assert re.search(r'<dd id="gw-uptime">\d\d:\d\d:\d\d</dd>', dom)
        assert re.search(r'<dd id="gw-local_time">\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d</dd>', dom)
        assert (f'<dd id="broker-detail" class="up">broker {mosquitto.host}:{mosquitto.port} connected since '
                in dom)
        if SCREENSHOT:
            await run_browser(binary, f"http://127.0.0.1:{http_port}/", f"--screenshot={SCREENSHOT}",
                              "--window-size=1400,640")


def broker_lines(caplog: pytest.LogCaptureFixture, address: str, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == "edge.publish.mqtt" and r.levelno >= level and address in r.getMessage()]


def statuses(sock: socket.socket) -> list[str]:
    """The STATUS= texts sd_notify sent so far (read without blocking)."""
    out = []
    while True:
        try:
            datagram = sock.recv(65536).decode()
        except BlockingIOError:
            return out
        out += [field[len("STATUS="):] for field in datagram.split("\n") if field.startswith("STATUS=")]


async def test_a_refusing_broker_is_one_warning_naming_it_and_shown_down_until_it_is_back(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    binary = mosquitto_binary()
    if binary is None:
        pytest.skip("mosquitto is not installed (make test installs it where it can)")
    caplog.set_level(logging.DEBUG, logger="edge.publish.mqtt")
    broker = Mosquitto(binary)  # not started: its port refuses
    address = f"{broker.host}:{broker.port}"
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.setblocking(False)
    seen: list[str] = []

    def read_statuses() -> list[str]:
        seen.extend(statuses(notify))
        return seen

    try:
        async with one_machine(broker, tmp_path, notifier=SystemdNotifier(str(tmp_path / "notify"))) as (
                _, http_port, daemon):
            publisher = daemon.publisher
            def attempts() -> int:  # every attempt leaves a record, at DEBUG once the outage is said
                return len([r for r in caplog.records if r.name == "edge.publish.mqtt"
                            and "connect failed" in r.getMessage() and str(broker.port) in r.getMessage()])

            await async_wait_for(lambda: attempts() >= 8, 40, interval=0.05,
                                 message="four refused attempts on each of the two connections")
            warnings = broker_lines(caplog, f"broker={address}", logging.WARNING)
            assert len(warnings) == 2, warnings  # one per connection (Sparkplug, JSON), not one per attempt
            assert all("reason=refused" in line and "Connection refused" in line for line in warnings), warnings
            clients = {s.client_id for _, s in publisher.broker_states()}
            assert {m.group(1) for line in warnings if (m := re.search(r"client_id=(\S+)", line))} == clients
            assert not [r for r in caplog.records if r.name == "edge.publish.mqtt" and r.levelno == logging.INFO
                        and "connect failed" in r.getMessage()]  # the attempts in between: DEBUG only

            doc = await status_json(http_port)
            broker_doc = doc["gateway"]["broker"]
            assert (broker_doc["connected"], broker_doc["address"]) == (False, address), broker_doc
            assert broker_doc["down_since"] and "Connection refused" in broker_doc["last_error"]
            assert doc["gateway"]["broker_connected"] is False
            status, _, body = await http_get(http_port, "/healthz")
            reasons = json.loads(body)["reasons"]
            assert status == 503 and any(f"broker {address} DOWN since" in r and "Connection refused" in r
                                         for r in reasons), reasons
            await async_wait_for(lambda: any(f"broker {address} DOWN since" in s and "Connection refused" in s
                                             for s in read_statuses()), 10, message="STATUS= says the broker is down")

            broker.start()
            await async_wait_for(lambda: publisher.connected, 30, message="reconnected once the broker is up")
            recovered = broker_lines(caplog, f"broker={address}", logging.INFO)
            recovered = [line for line in recovered if "available again" in line]
            assert len(recovered) == 2 and all(re.search(r"down_for=\d+s", line) for line in recovered), recovered
            doc = await status_json(http_port)
            assert doc["gateway"]["broker"]["connected"] and doc["gateway"]["broker"]["connected_since"]
            await async_wait_for(lambda: any(f"broker {address} connected since" in s for s in read_statuses()), 10,
                                 message="STATUS= says the broker is connected")
    finally:
        notify.close()
        broker.close()
