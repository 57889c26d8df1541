"""The NBIRTH states the gateway as it is: machines configured and connected (issue 16, point 11)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.publish import payload as pl
from edge.publish.sparkplug_b_pb2 import Payload
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer, metrics_by_name

pytestmark = pytest.mark.integration

REBIRTH = Payload(metrics=[Payload.Metric(name=pl.REBIRTH_METRIC, boolean_value=True)]).SerializeToString()


def machine(machine_id: str, port: int) -> str:
    return (f"  - {{id: {machine_id}, host: 127.0.0.1, port: {port}, "
            f"timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.5}}}}\n")


def gateway_counts(observer: Observer, index: int) -> tuple[int, int]:
    birth = metrics_by_name(observer.of("NBIRTH")[index].spb())
    return birth["Gateway/Machines"].int_value, birth["Gateway/MachinesConnected"].int_value


async def test_nbirth_states_machines_and_machines_connected(mosquitto: Mosquitto, observer: Observer,
                                                             tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="0i-F"), MachineSpec(profile="16i")],
                     base_port=0) as fleet:
        machines = "".join(machine(f"m{i + 1}", m.port) for i, m in enumerate(fleet))
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_count("NBIRTH", 1, timeout=15)
            for device in ("m1", "m2", "m3"):
                await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/{device}", timeout=15)
            # The first NBIRTH may come before any machine answered, never before they are configured.
            assert gateway_counts(observer, 0)[0] == 3
            await observer.publish("spBv1.0/plant/NCMD/gw", REBIRTH)
            await observer.wait_count("NBIRTH", 2, timeout=15)
            await async_wait_for(lambda: len(observer.of("DBIRTH")) >= 6, timeout=15, message="three DBIRTHs")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0
    assert gateway_counts(observer, 1) == (3, 3), "a rebirth with all three machines online states them"
