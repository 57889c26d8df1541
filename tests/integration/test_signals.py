"""Signals end to end: `focas-edge run` as a real subprocess against mosquitto and simulated CNCs.

SIGTERM: DDEATH for every machine, then NDEATH, exit 0 within seconds, every CNC session closed.
SIGHUP after editing the config: an added machine gets its DBIRTH, a removed one its DDEATH, and the
broker session stays (no new NBIRTH, same bdSeq, no NDEATH).

The subprocess helpers here are also used by test_systemd.py.
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.mqtt_observer import Observer, Received


def focas_edge_command() -> list[str]:
    script = Path(sys.executable).with_name("focas-edge")
    return [str(script)] if script.exists() else [sys.executable, "-m", "edge"]


def daemon_config(broker: Mosquitto, state_dir: Path, machines: dict[str, int],
                  polls: dict[str, str] | None = None) -> str:
    entries = "".join(
        f"  - {{id: {mid}, host: 127.0.0.1, port: {port}, "
        f"timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.3}}"
        f"{', poll: ' + polls[mid] if polls and mid in polls else ''}}}\n"
        for mid, port in machines.items())
    return f"""
mqtt:
  host: {broker.host}
  port: {broker.port}
  formats: [sparkplug, json]
  sparkplug: {{group_id: plant, edge_node_id: gw}}
state_dir: {state_dir}
machines:
{entries}
"""


class DaemonProcess:
    """`focas-edge run` in a subprocess; stderr goes to a file the test can show on failure."""

    def __init__(self, config: Path, env: dict[str, str] | None = None) -> None:
        self.config = config
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.log = config.with_suffix(".log")
        self.proc: asyncio.subprocess.Process | None = None

    async def start(self) -> None:
        log = self.log.open("wb")  # the child keeps its own copy of the descriptor
        try:
            self.proc = await asyncio.create_subprocess_exec(
                *focas_edge_command(), "--log-level", "INFO", "run", "--config", str(self.config),
                stdout=log, stderr=log, env=self.env)
        finally:
            log.close()

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def signal(self, sig: signal.Signals) -> None:
        assert self.proc is not None
        self.proc.send_signal(sig)

    async def wait(self, timeout: float) -> int:
        assert self.proc is not None
        return await asyncio.wait_for(self.proc.wait(), timeout)

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    async def kill(self) -> None:
        """Cleanup: only if it is still running (a passing test has already stopped it)."""
        if self.proc is not None and self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()


pytestmark = pytest.mark.integration

GROUP = "spBv1.0/plant"


def bdseq_of(message: Received) -> int:
    return next(int(m.long_value) for m in message.spb().metrics if m.name == "bdSeq")


@pytest.fixture
async def daemons() -> AsyncIterator[list[DaemonProcess]]:
    started: list[DaemonProcess] = []
    yield started
    for daemon in started:
        await daemon.kill()


async def test_sigterm_sends_ddeaths_then_ndeath_closes_cnc_sessions_and_exits_0(
        mosquitto: Mosquitto, observer: Observer, daemons: list[DaemonProcess], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="16i")], base_port=0) as fleet:
        config = tmp_path / "edge.yaml"
        config.write_text(daemon_config(mosquitto, tmp_path / "state", {"m1": fleet[0].port, "m2": fleet[1].port}))
        daemon = DaemonProcess(config)
        daemons.append(daemon)
        await daemon.start()
        for machine in ("m1", "m2"):
            await observer.wait_topic(f"{GROUP}/DDATA/gw/{machine}", timeout=20)
        assert fleet[0].sessions == 1 and fleet[1].sessions == 1
        daemon.signal(signal.SIGTERM)
        started = time.monotonic()
        code = await daemon.wait(10)
        assert code == 0, daemon.output()
        assert time.monotonic() - started < 5, "exit within seconds"
        await async_wait_for(lambda: fleet[0].sessions == 0 and fleet[1].sessions == 0, 5,
                             message="CNC sessions closed")
        await observer.wait_topic(f"{GROUP}/NDEATH/gw", timeout=5)
    kinds = [(m.kind, m.topic.rsplit("/", 1)[-1]) for m in observer.snapshot() if m.kind]
    ndeath = kinds.index(("NDEATH", "gw"))
    deaths = {device for kind, device in kinds[:ndeath] if kind == "DDEATH"}
    assert deaths == {"m1", "m2"}, kinds[-6:]
    assert not any(kind.startswith("D") for kind, _ in kinds[ndeath + 1:]), "nothing after NDEATH"
    (nbirth,) = observer.of("NBIRTH")
    assert bdseq_of(observer.of("NDEATH")[0]) == bdseq_of(nbirth)
    # No json prefix in this config: the default names the gateway (group plant, node gw).
    online = [m.payload.decode() for m in observer.on("focas/plant/gw/m1/online")]
    assert online[-1] == "offline"


async def test_sighup_applies_machines_added_and_removed_without_dropping_the_broker_session(
        mosquitto: Mosquitto, observer: Observer, daemons: list[DaemonProcess], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="16i"), MachineSpec(profile="0i-F")],
                     base_port=0) as fleet:
        ports = {"m1": fleet[0].port, "m2": fleet[1].port, "m3": fleet[2].port}
        config = tmp_path / "edge.yaml"
        state = tmp_path / "state"
        config.write_text(daemon_config(mosquitto, state, {"m1": ports["m1"], "m2": ports["m2"]}))
        daemon = DaemonProcess(config)
        daemons.append(daemon)
        await daemon.start()
        for machine in ("m1", "m2"):
            await observer.wait_topic(f"{GROUP}/DBIRTH/gw/{machine}", timeout=20)
        (nbirth,) = await observer.wait_count("NBIRTH", 1)
        # Edit the file: m2 removed, m3 added with a faster period, m1 unchanged; then SIGHUP.
        config.write_text(daemon_config(mosquitto, state, {"m1": ports["m1"], "m3": ports["m3"]},
                                        {"m3": "{periods: {status: 60ms}}"}))
        daemon.signal(signal.SIGHUP)
        await observer.wait_topic(f"{GROUP}/DBIRTH/gw/m3", timeout=15)
        assert "reload: poll grid 0.05s -> 0.03s" in daemon.output()  # auto: half of m3's period, at once
        await observer.wait_topic(f"{GROUP}/DDEATH/gw/m2", timeout=15)
        await async_wait_for(lambda: fleet[1].sessions == 0, 5, message="m2's CNC session closed")
        m1_before = len(observer.on(f"{GROUP}/DDATA/gw/m1"))
        await async_wait_for(lambda: len(observer.on(f"{GROUP}/DDATA/gw/m1")) > m1_before + 2, 10,
                             message="m1 keeps publishing after the reload")
        assert len(observer.of("NBIRTH")) == 1, "the broker session was not dropped"
        assert observer.of("NDEATH") == []
        assert observer.on(f"{GROUP}/DDEATH/gw/m1") == [] and len(observer.on(f"{GROUP}/DBIRTH/gw/m1")) == 1
        # m3's birth belongs to the same session: same bdSeq era, seq continues (no reset to 0).
        m3_birth = observer.on(f"{GROUP}/DBIRTH/gw/m3")[0].spb()
        assert m3_birth.seq != 0 or len(observer.snapshot()) > 256

        # A broken edit is refused and the running config is kept.
        config.write_text("mqtt: {host: nowhere\n")
        daemon.signal(signal.SIGHUP)
        await async_wait_for(lambda: "reload refused" in daemon.output(), 10, message="reload refused log")
        count = len(observer.on(f"{GROUP}/DDATA/gw/m3"))
        await async_wait_for(lambda: len(observer.on(f"{GROUP}/DDATA/gw/m3")) > count, 10,
                             message="m3 still polled")
        daemon.signal(signal.SIGTERM)
        assert await daemon.wait(10) == 0, daemon.output()
    assert bdseq_of(observer.of("NDEATH")[-1]) == bdseq_of(nbirth)
