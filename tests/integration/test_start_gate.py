"""The daemon's start-up gate with real simulated CNCs: every machine born through a gate of one place, and a
machine whose CNC does not answer never holds that place (edge.collect.start_gate)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from edge.collect import StartGate
from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

TIMEOUTS = "timeouts: {request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.5}"


async def test_every_machine_is_born_through_a_gate_of_one_and_a_silent_cnc_holds_no_place(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i") for _ in range(4)], base_port=0) as fleet:
        machines = "".join(f"  - {{id: m{i + 1}, host: 127.0.0.1, port: {m.port}, {TIMEOUTS}}}\n"
                           for i, m in enumerate(fleet))
        machines += f"  - {{id: silent, host: 127.0.0.1, port: {free_port()}, {TIMEOUTS}}}\n"  # nothing listens
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        gate = daemon.start_gate = StartGate(1)
        task = asyncio.create_task(daemon.run())
        try:
            for i in range(4):
                await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/m{i + 1}", timeout=30)
            await async_wait_for(lambda: daemon.pollers["silent"].stats.connects == 0
                                 and "connect failed" in daemon.pollers["silent"].last_error, timeout=10,
                                 message="the silent CNC's connect failing")
            assert gate.peak == 1
            await async_wait_for(lambda: gate.starting == 0, timeout=5, message="every place given back")
            assert not observer.on("spBv1.0/plant/DBIRTH/gw/silent")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
