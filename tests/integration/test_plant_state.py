"""The machine state in the MES vocabulary, end to end (issue 27 points 1, 2): a simulated 30i driven over its
admin endpoint through cutting, feed hold, emergency stop, alarm and a dropped session; Status/Execution and
Status/Availability on Sparkplug and JSON, CNC-stamped; utilisation counters published and kept across a restart."""

from __future__ import annotations

import asyncio
import json
import time
import urllib.request
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.admin import AdminServer
from edge.sim.fleet import Fleet, MachineSpec
from edge.sim.state_program import CycleSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

ALWAYS_CUTTING = CycleSpec(cut_seconds=3600.0, idle_seconds=1.0, alarm_every=0)


def post(url: str, body: dict[str, object]) -> None:
    request = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=5):
        pass


def sparkplug_values(observer: Observer, device: str, name: str) -> list[tuple[object, int]]:
    """(value, timestamp) of metric `name` in the device's DBIRTHs and DDATAs, in arrival order."""
    aliases: dict[int, str] = {}
    out: list[tuple[object, int]] = []
    for message in observer.snapshot():
        if message.topic == f"spBv1.0/plant/DBIRTH/gw/{device}":
            aliases = {m.alias: m.name for m in message.spb().metrics}
        elif message.topic != f"spBv1.0/plant/DDATA/gw/{device}":
            continue
        for metric in message.spb().metrics:
            if (metric.name or aliases.get(metric.alias)) == name:
                kind = metric.WhichOneof("value")
                out.append((getattr(metric, kind) if kind else None, metric.timestamp))
    return out


def json_values(observer: Observer, device: str, name: str) -> list[dict[str, object]]:
    return [json.loads(m.payload) for m in observer.on(f"focas/{device}/state/{name}")]


async def wait_state(observer: Observer, name: str, value: str, timeout: float = 15) -> None:
    """Until the last `name` on BOTH formats is `value`."""
    def shown() -> bool:
        spb, js = sparkplug_values(observer, "m1", name), json_values(observer, "m1", name)
        return bool(spb and js and spb[-1][0] == value and js[-1]["value"] == value)
    await async_wait_for(shown, timeout=timeout, message=f"{name} {value} on Sparkplug and JSON")


async def test_execution_follows_the_machine_on_sparkplug_and_json_and_utilisation_survives_a_restart(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i", cycle=ALWAYS_CUTTING, seed=0)], base_port=0) as fleet, \
            AdminServer(fleet) as admin:
        state_url = admin.url + "/machines/0/state"
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, timezone: Europe/Berlin, "
                    "timeouts: {backoff_initial_s: 0.1, backoff_max_s: 0.3}, poll: {periods: {status: 0.1s}}}\n")
        config = parse_config(daemon_config(mosquitto, tmp_path, machines))
        daemon = Daemon(config)
        task = asyncio.create_task(daemon.run())
        try:
            await wait_state(observer, "Status/Execution", "ACTIVE")
            assert sparkplug_values(observer, "m1", "Status/Availability")[-1][0] == "AVAILABLE"
            assert json_values(observer, "m1", "Status/ControllerMode")[-1]["value"] == "AUTOMATIC"

            await asyncio.to_thread(post, state_url, {"feed_hold": True})
            await wait_state(observer, "Status/Execution", "FEED_HOLD")
            await asyncio.to_thread(post, state_url, {"feed_hold": False, "emergency": True})
            await wait_state(observer, "Status/Execution", "STOPPED")
            await async_wait_for(lambda: any(isinstance(d["value"], float) and d["value"] > 0
                                             for d in json_values(observer, "m1", "Utilisation/FEED_HOLD")),
                                 timeout=10, message="feed hold seconds published on the change of state")
            await asyncio.to_thread(post, state_url, {"emergency": False,
                                                      "raise_alarm": {"number": 1004, "type": "EX"}})
            await wait_state(observer, "Status/Execution", "ACTIVE")  # the simulator cuts on with the alarm

            # The session drops and stays down: UNAVAILABLE on both formats, before the death.
            await asyncio.to_thread(post, admin.url + "/machines/0/faults", {"max_sessions": 0, "drop_now": True})
            dropped_ms = time.time() * 1000
            await wait_state(observer, "Status/Availability", "UNAVAILABLE")
            topics = [m.topic for m in observer.snapshot() if m.topic.startswith("spBv1.0/plant/D")]
            assert topics.index("spBv1.0/plant/DDEATH/gw/m1") > max(
                i for i, t in enumerate(topics) if t == "spBv1.0/plant/DDATA/gw/m1")
            stamp = sparkplug_values(observer, "m1", "Status/Availability")[-1][1]
            assert abs(stamp - dropped_ms) < 5000
            alarm_s = sparkplug_values(observer, "m1", "Utilisation/ALARM")[-1][0]
            assert isinstance(alarm_s, float) and alarm_s > 0  # counted until the drop, published with it
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
        saved = json.loads((tmp_path / "utilisation" / "m1.json").read_text())
        assert saved["seconds"]["FEED_HOLD"] > 0 and saved["seconds"]["OFFLINE"] > 0

        # A new daemon on the same state_dir: the day's counters go on; the time it was down is UNKNOWN.
        await asyncio.to_thread(post, admin.url + "/machines/0/faults", {"clear": True})
        births = len(observer.on("spBv1.0/plant/DBIRTH/gw/m1"))
        await asyncio.sleep(1.0)  # the gateway is down for a second: that second must count as UNKNOWN
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=births + 1, timeout=15)
            birth = {m.name: m for m in observer.on("spBv1.0/plant/DBIRTH/gw/m1")[-1].spb().metrics}
            assert birth["Utilisation/FEED_HOLD"].double_value == pytest.approx(saved["seconds"]["FEED_HOLD"])
            assert birth["Utilisation/UNKNOWN"].double_value >= saved["seconds"].get("UNKNOWN", 0.0) + 1.0
            assert birth["Utilisation/Day"].string_value == saved["day"]
            assert birth["Status/Availability"].string_value == "AVAILABLE"
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0


async def test_each_path_of_a_two_path_lathe_has_its_own_execution_and_utilisation(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """Path 2 is its own device (`m1-path2`, as for Status/Run): its own Execution, counters and state file."""
    async with Fleet([MachineSpec(profile="31i-2p", cycle=ALWAYS_CUTTING, seed=0)], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, paths: 2, "
                    "poll: {periods: {status: 0.1s}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        try:
            for device in ("m1", "m1-path2"):
                await observer.wait_topic(f"focas/{device}/state/Status/Execution", timeout=15)
                await observer.wait_topic(f"focas/{device}/state/Utilisation/Day", timeout=15)
            second = fleet[0].state.for_path(2)
            assert second is not None
            second.set_feed_hold(True)  # path 2 held, path 1 cuts on
            await async_wait_for(
                lambda: json_values(observer, "m1-path2", "Status/Execution")[-1]["value"] == "FEED_HOLD",
                timeout=10, message="path 2 in feed hold")
            assert json_values(observer, "m1", "Status/Execution")[-1]["value"] in ("ACTIVE", "WAIT")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    assert {p.name for p in (tmp_path / "utilisation").iterdir()} == {"m1.json", "m1-path2.json"}
