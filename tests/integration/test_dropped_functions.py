"""A function dropped after EW_FUNC/EW_NOOPT is tried again: after a reconnect, and at `poll.retry_dropped`
within a session, so one transient answer does not end a data stream until restart (issue 16, point 13)."""

from __future__ import annotations

import asyncio
import json
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

LOAD = "focas/m1/state/Spindle/1/Load"


def config(broker: Mosquitto, state_dir: Path, port: int, poll: str = "") -> str:
    machine = (f"  - {{id: m1, host: 127.0.0.1, port: {port}, poll: {{periods: {{status: 0.1s}}{poll}}}, "
               f"timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.3}}}}\n")
    return daemon_config(broker, state_dir, machine)


def states(observer: Observer, topic: str) -> list[dict[str, object]]:
    return [json.loads(m.payload) for m in observer.on(topic)]


def good_load_after(observer: Observer, index: int) -> bool:
    """A good Spindle/1/Load value published after the first `index` documents."""
    return any(doc.get("quality", "GOOD") == "GOOD" and doc["value"] is not None
               for doc in states(observer, LOAD)[index:])


async def wait_dropped(observer: Observer) -> None:
    def dropped() -> bool:
        docs = states(observer, "focas/m1/state/Plan/DroppedFunctions")
        return bool(docs) and "SpindleLoad" in str(docs[-1]["value"])
    await async_wait_for(dropped, timeout=15, message="spindle load dropped from the plan")


async def test_dropped_function_is_retried_at_the_slow_cadence(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="edge.collect.poller")
    async with Fleet([MachineSpec(profile="30i", faults={"ew": {"spindle_load": 1}})], base_port=0) as fleet:
        daemon = Daemon(parse_config(config(mosquitto, tmp_path, fleet[0].port, ", retry_dropped: 0.5s")))
        task = asyncio.create_task(daemon.run())
        try:
            await wait_dropped(observer)
            # Still refused at the first retries: dropped again, said at INFO, not a WARNING each time.
            await async_wait_for(lambda: daemon.pollers["m1"].stats.item_errors.get("EW_FUNC", 0) >= 3,
                                 timeout=15, message="retried twice")
            seen = len(states(observer, LOAD))
            fleet[0].faults.update({"ew": {}})  # the control answers again
            await async_wait_for(lambda: good_load_after(observer, seen), timeout=15,
                                 message="spindle load published again")
            await async_wait_for(
                lambda: states(observer, "focas/m1/state/Plan/DroppedFunctions")[-1]["value"] == "",
                timeout=15, message="Plan/DroppedFunctions empty again")
            births = len(observer.on("spBv1.0/plant/DBIRTH/gw/m1"))
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    assert births == 1, "retried within the session: no reconnect, no rebirth"
    drops = [r for r in caplog.records if "dropped from plan" in r.getMessage()]
    assert [r.levelno for r in drops][:1] == [logging.WARNING] and len(drops) >= 3
    assert all(r.levelno == logging.INFO for r in drops[1:]), "a repeated drop is not a new WARNING"


async def test_dropped_function_is_tried_again_after_a_reconnect(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i", faults={"ew": {"spindle_load": 1}})], base_port=0) as fleet:
        daemon = Daemon(parse_config(config(mosquitto, tmp_path, fleet[0].port)))  # retry: 10 min default
        task = asyncio.create_task(daemon.run())
        try:
            await wait_dropped(observer)
            fleet[0].faults.update({"ew": {}})
            seen = len(states(observer, LOAD))
            fleet[0].drop_connections()
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=2, timeout=15)
            await async_wait_for(lambda: good_load_after(observer, seen), timeout=15,
                                 message="spindle load published after the reconnect")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    rebirth = metrics_by_name(observer.on("spBv1.0/plant/DBIRTH/gw/m1")[1].spb())
    assert rebirth["Plan/DroppedFunctions"].string_value == ""
    assert not rebirth["Spindle/1/Load"].is_null
