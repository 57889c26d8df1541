"""A CNC clock set back 30 s (within max_skew_s) while the daemon polls it (issue 16, point 12): the step is
logged once, Clock/Skew re-synced at once, and no published value is stamped before one already sent."""

from __future__ import annotations

import asyncio
import json
import logging
import re
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration


def skew(observer: Observer) -> float | None:
    docs = [json.loads(m.payload) for m in observer.on("focas/m1/state/Clock/Skew")]
    return float(docs[-1]["value"]) if docs and docs[-1]["value"] is not None else None


async def test_clock_set_back_30s_is_logged_once_and_never_stamps_back(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="edge.collect.poller")
    machine = ("  - {id: m1, host: 127.0.0.1, port: %d, poll: {periods: {status: 0.1s}}, max_skew_s: 60}\n")
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machine % fleet[0].port)))
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            await async_wait_for(lambda: (s := skew(observer)) is not None and abs(s) < 1.0, timeout=15,
                                 message="CNC time in use")
            await async_wait_for(lambda: len(observer.on("spBv1.0/plant/DDATA/gw/m1")) >= 10, timeout=15,
                                 message="data stamped with CNC time before the step")
            fleet[0].state.clock_offset = -30.0  # someone sets the control's clock back
            await async_wait_for(lambda: (s := skew(observer)) is not None and abs(s + 30.0) < 1.0, timeout=15,
                                 message="Clock/Skew re-synced to -30 s")
            seen = len(observer.on("spBv1.0/plant/DDATA/gw/m1"))
            await async_wait_for(lambda: len(observer.on("spBv1.0/plant/DDATA/gw/m1")) > seen + 20, timeout=15,
                                 message="more data after the step")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0
    latest = 0
    for message in observer.on("spBv1.0/plant/DDATA/gw/m1"):
        stamps = [m.timestamp for m in message.spb().metrics]
        assert min(stamps) >= latest, f"a value stamped {latest - min(stamps)} ms before one already sent"
        latest = max(latest, *stamps)
    steps = [r for r in caplog.records if "CNC clock stepped" in r.getMessage()]
    assert len(steps) == 1 and steps[0].levelno == logging.WARNING, [r.getMessage() for r in steps]
    assert re.search(r"machine=m1 step=-(29|30)\.\d+s", steps[0].getMessage()), steps[0].getMessage()
