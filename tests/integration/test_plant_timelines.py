"""The plant page's timelines are recorded and saved only where the page can show them (`http.enabled`):
with the status page off, a daemon polls and publishes as before and leaves no timeline file behind."""

from __future__ import annotations

from pathlib import Path

import pytest

from edge.service.daemon import Daemon
from edge.service.trend_store import TRENDS_FILE
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, free_port
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer
from tests.integration.test_daemon import machine_entry, start_daemon, stop_daemon

pytestmark = pytest.mark.integration


async def run_until_data(mosquitto: Mosquitto, observer: Observer, state_dir: Path, http: str) -> Daemon:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        daemon, task = await start_daemon(daemon_config(mosquitto, state_dir, machine_entry("m1", fleet[0].port), http))
        try:
            await observer.wait_count("DDATA", 2, timeout=15)
        finally:
            await stop_daemon(daemon, task)
    return daemon


async def test_without_the_status_page_no_timeline_is_recorded_or_saved(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    daemon = await run_until_data(mosquitto, observer, tmp_path, "http: {enabled: false}")
    assert daemon.trends is None
    assert not (tmp_path / TRENDS_FILE).exists()


async def test_with_the_status_page_the_day_is_saved_at_shutdown(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    daemon = await run_until_data(mosquitto, observer, tmp_path,
                                  f"http: {{enabled: true, host: 127.0.0.1, port: {free_port()}}}")
    assert daemon.trends is not None and "m1" in daemon.trends.machines
    assert (tmp_path / TRENDS_FILE).exists()
