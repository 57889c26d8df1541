"""A read that fails with anything but EW_FUNC/EW_NOOPT is an error of its function until it answers again:
counted per function, the last error, listed as failing (issue 24). The reads outside the tick loop too: the
axis names read once per session (without them the session publishes no axis metric) and the CNC clock."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.test_dropped_functions import config

pytestmark = pytest.mark.integration

EW_DATA = 5  # not "function not available": the read fails, it is not dropped


async def test_axis_names_and_clock_errors_are_counted_and_failing_until_they_answer(
        mosquitto: Mosquitto, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="edge.collect.poller")
    faults = {"ew": {"axis_names": EW_DATA, "read_clock": EW_DATA}}
    async with Fleet([MachineSpec(profile="30i", faults=faults)], base_port=0) as fleet:
        daemon = Daemon(parse_config(config(mosquitto, tmp_path, fleet[0].port)))
        task = asyncio.create_task(daemon.run())
        try:
            await async_wait_for(lambda: "m1" in daemon.pollers, timeout=15, message="the poller")
            poller = daemon.pollers["m1"]
            await async_wait_for(lambda: "ReadClock" in poller.last_error and "EW_DATA" in poller.last_error,
                                 timeout=15, message="the clock's error as the machine's last error")
            await async_wait_for(lambda: poller.stats.errors.get(("ReadClock", "EW_DATA"), 0) >= 3, timeout=15,
                                 message="clock errors counted per tick")
            assert poller.stats.errors[("ReadAxisNames", "EW_DATA")] == 1  # read once per session
            assert sorted(poller.stats.failing) == ["ReadAxisNames", "ReadClock"]
            assert poller.stats.failing["ReadClock"].errors >= 3

            fleet[0].faults.update({"ew": {}})  # the control answers again
            await async_wait_for(lambda: "ReadClock" not in poller.stats.failing, timeout=15,
                                 message="the clock answers again")
            assert "ReadAxisNames" in poller.stats.failing  # this session has no axis metrics: still so
            fleet[0].drop_connections()
            await async_wait_for(lambda: not poller.stats.failing and poller.online, timeout=15,
                                 message="the axis names answer in the next session")
            await async_wait_for(lambda: any(name.startswith("Axis/") for name in poller.last_values()),
                                 timeout=15, message="axis metrics in the new session")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    messages = [(r.levelno, r.getMessage()) for r in caplog.records if "function=Read" in r.getMessage()]
    failing = [m for level, m in messages if level == logging.WARNING and m.startswith("read failing")]
    again = [m for level, m in messages if level == logging.INFO and m.startswith("read answers again")]
    assert len(failing) == 2 and len(again) == 2, messages  # one line when it starts, one when it ends
