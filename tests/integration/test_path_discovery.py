"""The daemon asks a control's path count at connect (issue 18 §1): `Device/Paths` in the machine's DBIRTH,
one WARNING naming `paths: N` when the control has more paths than configured, and a configured path the
control lacks stays offline with an error naming the key. The simulator over TCP, a real mosquitto."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer, metrics_by_name

pytestmark = pytest.mark.integration


def _path_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.levelno == logging.WARNING and r.name == "edge.collect.path_check"]


async def test_a_two_path_control_configured_with_one_path_says_which_key_to_add(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """`paths` left at 1 on the two-path lathe: the DBIRTH says Device/Paths 2 and one WARNING names
    `paths: 2`; a reconnect asks again but does not warn again."""
    caplog.set_level(logging.WARNING, logger="edge.collect.path_check")
    async with Fleet([MachineSpec(profile="31i-2p")], base_port=0) as fleet:
        machines = f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, poll: {{periods: {{status: 0.1s}}}}}}\n"
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        try:
            birth = (await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15))[0]
            metric = metrics_by_name(birth.spb())["Device/Paths"]
            assert (metric.int_value, metric.datatype) == (2, 3)  # Int32
            await async_wait_for(lambda: _path_warnings(caplog), timeout=10, message="the paths warning")
            (warning,) = _path_warnings(caplog)
            assert "`paths: 2`" in warning and "m1" in warning
            assert fleet[0].drop_connections() >= 1
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=2, timeout=20)
            assert len(_path_warnings(caplog)) == 1
            assert not observer.on("spBv1.0/plant/DBIRTH/gw/m1-path2")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0


async def test_a_configured_path_the_control_lacks_stays_offline_with_a_clear_error(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """`paths: 2` on a single-path control: path 1 is born with Device/Paths 1, device m1-path2 is never
    born and its poller's error says path 2 is not on the control and names `paths:`."""
    caplog.set_level(logging.WARNING, logger="edge.collect.path_check")
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, paths: 2, "
                    f"poll: {{periods: {{status: 0.1s}}}}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        try:
            birth = (await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15))[0]
            assert metrics_by_name(birth.spb())["Device/Paths"].int_value == 1
            second = daemon.pollers["m1-path2"]
            await async_wait_for(lambda: "EW_PATH" in second.last_error, timeout=15,
                                 message="the path-2 device's connect error")
            assert "path 2 is not on this control" in second.last_error and "`paths:`" in second.last_error
            assert not second.online and not observer.on("spBv1.0/plant/DBIRTH/gw/m1-path2")
            (warning,) = _path_warnings(caplog)
            assert "m1-path2" in warning and "`paths: 1`" in warning
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
