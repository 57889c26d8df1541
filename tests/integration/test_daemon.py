"""The collector daemon end to end: simulated CNCs over TCP -> daemon -> real mosquitto -> a subscriber."""

from __future__ import annotations

import asyncio
import json
import time
from datetime import UTC
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer, metrics_by_name

pytestmark = pytest.mark.integration


config_text = daemon_config


def machine_entry(machine_id: str, port: int, **fields: object) -> str:
    extra = "".join(f", {k}: {json.dumps(v)}" for k, v in fields.items())
    return (f"  - {{id: {machine_id}, host: 127.0.0.1, port: {port}{extra}, "
            f"timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.5}}}}\n")


async def start_daemon(text: str) -> tuple[Daemon, asyncio.Task[int]]:
    daemon = Daemon(parse_config(text))
    task = asyncio.create_task(daemon.run())
    return daemon, task


async def stop_daemon(daemon: Daemon, task: asyncio.Task[int]) -> None:
    daemon.request_stop()
    assert await asyncio.wait_for(task, 15) == 0


def ddata_metrics(observer: Observer, device: str) -> list[tuple[int, object]]:
    """(alias or name, metric) of every DDATA metric for a device, in arrival order."""
    out = []
    for message in observer.on(f"spBv1.0/plant/DDATA/gw/{device}"):
        out.extend(message.spb().metrics)
    return out


def birth_aliases(observer: Observer, device: str) -> dict[int, str]:
    births = observer.on(f"spBv1.0/plant/DBIRTH/gw/{device}")
    assert births, f"no DBIRTH for {device}"
    return {m.alias: m.name for m in births[-1].spb().metrics}


def json_state(observer: Observer, device: str, metric: str) -> list[dict[str, object]]:
    return [json.loads(m.payload) for m in observer.on(f"focas/{device}/state/{metric}")]


async def test_published_timestamps_are_cnc_time(mosquitto: Mosquitto, observer: Observer,
                                                 tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i", clock_offset=37.0)], base_port=0) as fleet:
        text = config_text(mosquitto, tmp_path, machine_entry("m1", fleet[0].port, max_skew_s=120))
        daemon, task = await start_daemon(text)
        try:
            await observer.wait_count("DDATA", 5, timeout=15)
        finally:
            await stop_daemon(daemon, task)
    aliases = birth_aliases(observer, "m1")
    birth = observer.on("spBv1.0/plant/DBIRTH/gw/m1")[-1].spb()
    skew = metrics_by_name(birth)["Clock/Skew"]
    assert 36.0 < skew.double_value < 38.0, skew
    # Every data metric stamped with CNC time: 37 s ahead of when we received it.
    for message in observer.of("DDATA"):
        received_ms = time.time() * 1000
        for metric in message.spb().metrics:
            assert aliases[metric.alias]  # alias only in data
            lead_s = (metric.timestamp - received_ms) / 1000
            assert 30.0 < lead_s < 38.5, (aliases[metric.alias], lead_s)
    runs = json_state(observer, "m1", "Status/Run")
    assert runs and all(30_000 < int(r["ts"]) - time.time() * 1000 < 38_500 for r in runs)  # type: ignore[call-overload]


async def test_skew_beyond_limit_uses_gateway_time_then_recovers(mosquitto: Mosquitto, observer: Observer,
                                                                 tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="16i", clock_offset=37.0)], base_port=0) as fleet:
        text = config_text(mosquitto, tmp_path, machine_entry("m1", fleet[0].port, max_skew_s=10))
        daemon, task = await start_daemon(text)
        try:
            await observer.wait_topic("focas/m1/state/Clock/UsingGatewayTime", timeout=15)
            flag = json_state(observer, "m1", "Clock/UsingGatewayTime")[-1]
            assert flag["value"] is True
            assert abs(int(flag["ts"]) - time.time() * 1000) < 3000  # type: ignore[call-overload]
            fleet[0].state.clock_offset = 0.0  # the CNC clock is set right
            await async_wait_for(
                lambda: json_state(observer, "m1", "Clock/UsingGatewayTime")[-1]["value"] is False,
                timeout=15, message="recovery to CNC time")
        finally:
            await stop_daemon(daemon, task)


async def test_machine_that_goes_away_gets_ddeath_and_rebirths_while_others_publish(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="0i-F")], base_port=0) as fleet:
        machines = machine_entry("m1", fleet[0].port) + machine_entry("m2", fleet[1].port)
        daemon, task = await start_daemon(config_text(mosquitto, tmp_path, machines))
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m2", timeout=15)
            fleet[0].faults.update({"refuse": -1})
            fleet[0].drop_connections()
            await observer.wait_topic("spBv1.0/plant/DDEATH/gw/m1", timeout=15)
            during = len(observer.on("spBv1.0/plant/DDATA/gw/m2"))
            await async_wait_for(lambda: len(observer.on("spBv1.0/plant/DDATA/gw/m2")) >= during + 3,
                                 timeout=10, message="m2 keeps publishing while m1 is down")
            fleet[0].faults.clear()
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=2, timeout=15)
        finally:
            await stop_daemon(daemon, task)
    m1 = [m.kind for m in observer.snapshot() if m.topic.endswith("/m1") and m.kind]
    death = m1.index("DDEATH")
    rebirth = m1.index("DBIRTH", death)
    assert "DDATA" not in m1[death:rebirth], "no data between DDEATH and the new DBIRTH"
    statuses = [m.payload.decode() for m in observer.on("focas/m1/online")]
    assert statuses[:3] == ["online", "offline", "online"]


async def test_alarm_history_events_carry_ring_times_and_are_published_once(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0, packed_base_port=0) as fleet:
        state = fleet[0].state
        # The CNC reports whole seconds of its wall clock (here UTC, the machine's configured zone).
        ring_ms = {round(e.local_time.replace(tzinfo=UTC).timestamp() * 1000) for e in state.alarm_events()}
        assert ring_ms, "the simulator seeds an alarm history"
        machines = (f"  - {{id: m1, transport: packed, address: 'tcp:127.0.0.1:{fleet[0].packed_port}'}}\n")
        text = config_text(mosquitto, tmp_path, machines,
                           "alarms: {mode: ActivePlusHistory, history_interval: 1s}")

        def history() -> list[dict[str, object]]:
            docs = [json.loads(m.payload) for m in observer.on("focas/m1/events/alarm")]
            return [json.loads(d["value"]) for d in docs if d["name"] == "Alarm/History"]

        daemon, task = await start_daemon(text)
        try:
            await async_wait_for(lambda: len(history()) >= len(ring_ms), timeout=15, message="history events")
        finally:
            await stop_daemon(daemon, task)
        first = history()
        assert {int(e["occurred_ms"]) for e in first} == ring_ms  # type: ignore[call-overload]
        assert len(first) == len(ring_ms)

        # Restart the daemon and reconnect the CNC: nothing is published again; a new alarm once.
        daemon, task = await start_daemon(text)
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=2, timeout=15)
            state.raise_alarm(1234, message="NEW ALARM")
            await async_wait_for(lambda: len(history()) > len(first), timeout=15, message="new alarm event")
            polls_before = len(observer.on("spBv1.0/plant/DDATA/gw/m1"))
            await async_wait_for(lambda: len(observer.on("spBv1.0/plant/DDATA/gw/m1")) > polls_before + 8,
                                 timeout=15, message="more polling after the new alarm")
        finally:
            await stop_daemon(daemon, task)
    later = history()[len(first):]
    assert [e["number"] for e in later] == [1234]


async def test_birth_carries_static_identity(mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="16i")], base_port=0) as fleet:
        daemon, task = await start_daemon(config_text(mosquitto, tmp_path, machine_entry("m1", fleet[0].port)))
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
        finally:
            await stop_daemon(daemon, task)
    metrics = metrics_by_name(observer.on("spBv1.0/plant/DBIRTH/gw/m1")[0].spb())
    assert metrics["Device/Model"].string_value.startswith("16i")
    assert metrics["Device/MaxAxis"].int_value == 8
    assert not metrics["Device/Model"].is_null


def test_run_refuses_a_bad_config_listing_every_problem(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from edge.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("""
mqtt: {host: 127.0.0.1, port: 99999, formats: [sparkplug], password: hunter2}
machines:
  - {id: m1, host: 127.0.0.1, timezone: Mars/Olympus}
  - {id: m1, host: 127.0.0.1, poll: {pmc: [{range: R103-R100}]}}
""")
    assert main(["run", "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    for fragment in ("mqtt.port", "mqtt.password", "mqtt.sparkplug", "machines[0].timezone", "machines[1].id",
                     "machines[1].poll.pmc[0]"):
        assert fragment in err, (fragment, err)
    assert "hunter2" not in err  # a secret is never echoed
