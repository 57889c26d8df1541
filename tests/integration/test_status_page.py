"""The status page at `/` of a running daemon (simulator over TCP, real mosquitto): the JSON document it
polls, the server-rendered HTML, and the page as headless Chromium shows it after its script has run."""

from __future__ import annotations

import asyncio
import json
import os
import re
import shutil
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, port_open
from tests.integration.test_status_http import config_text, http_get

pytestmark = pytest.mark.integration

# Set to a PNG path to keep a screenshot of the page the browser test loaded (never written by default).
SCREENSHOT = os.environ.get("STATUS_PAGE_SCREENSHOT", "")


def chromium() -> str | None:
    return next((path for name in ("chromium", "chromium-browser", "google-chrome")
                 if (path := shutil.which(name))), None)


async def run_browser(binary: str, url: str, *flags: str) -> str:
    """Headless Chromium on `url`; its stdout. Up to 8 s of page time lets the script poll several times."""
    proc = await asyncio.create_subprocess_exec(
        binary, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-extensions",
        f"--user-data-dir={Path('/tmp') / f'focas-edge-chromium-{free_port()}'}",
        "--virtual-time-budget=8000", *flags, url,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL)
    try:
        out, _ = await asyncio.wait_for(proc.communicate(), 90)
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    return out.decode(errors="replace")


async def rates_measured(http_port: int) -> bool:
    """The page's poll rate needs two reads of the document at least 0.5 s apart."""
    doc = json.loads((await http_get(http_port, "/status.json"))[2])
    return all(m["achieved_hz"] is not None for m in doc["machines"])


class RunningDaemon:
    """A daemon on the test's loop with two simulated CNCs: m1 (30i, one alarm raised), m2 (16i, refuses macros)."""

    def __init__(self, fleet: Fleet, mosquitto: Mosquitto, tmp_path: Path) -> None:
        self.http_port = free_port()
        fleet[1].faults.update({"ew": {"read_macros": 6}})
        fleet[0].state.raise_alarm(1001, message="SPINDLE OVERHEAT")
        text = config_text(mosquitto, tmp_path, [fleet[0].port, fleet[1].port], self.http_port, 0.5)
        text = text.replace(f"port: {fleet[1].port},", f"port: {fleet[1].port}, poll: {{macros: ['500-501']}},")
        self.daemon = Daemon(parse_config(text))

    async def __aenter__(self) -> RunningDaemon:
        self.task = asyncio.create_task(self.daemon.run())
        await async_wait_for(lambda: port_open("127.0.0.1", self.http_port), 10, message="status endpoint")
        await async_wait_for(lambda: all(p.online and p.stats.ticks > 3 for p in self.daemon.pollers.values())
                             and "ReadMacros" in self.daemon.pollers["m2"].dropped, 20,
                             message="both machines polling, m2's macros dropped")
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.daemon.request_stop()
        await asyncio.wait_for(self.task, 20)


async def test_status_json_and_the_server_rendered_page(mosquitto: Mosquitto, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="16i")], base_port=0) as fleet, \
            RunningDaemon(fleet, mosquitto, tmp_path) as running:
        status, headers, body = await http_get(running.http_port, "/status.json")
        assert status == 200 and headers["content-type"] == "application/json"
        doc = json.loads(body)
        gateway = {k: v for k, v in doc["gateway"].items() if k not in ("identity", "broker")}
        assert gateway == {"broker_connected": True, "spool_depth": 0, "writes_enabled": False,
                           "machines": 2, "machines_connected": 2, "identity_conflict": None}
        m1, m2 = doc["machines"]
        assert (m1["id"], m1["connected"], m1["series"], m1["planned_hz"]) == ("m1", True, "30i-BM", 4.0)
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d", m1["since"])  # local, offset
        assert {"number": 1001, "type": m1["alarms"][0]["type"], "axis": 0, "message": "SPINDLE OVERHEAT"} \
            in m1["alarms"]
        assert any(v["name"] == "Status/Run" for v in m1["values"])
        assert m2["dropped"] == ["ReadMacros"] and "ReadMacros" in m2["last_error"]
        await async_wait_for(lambda: rates_measured(running.http_port), 10, interval=0.1, message="poll rates")
        doc = json.loads((await http_get(running.http_port, "/status.json"))[2])
        assert all(m["achieved_hz"] > 0 for m in doc["machines"])
        status, headers, page = await http_get(running.http_port, "/")
        assert status == 200 and headers["content-type"].startswith("text/html")
        text = page.decode()
        assert "<tr id=\"machine-m1\">" in text and "SPINDLE OVERHEAT" in text and "ReadMacros" in text
        assert "writes</dt><dd id=\"writes\">off" in text


async def test_chromium_shows_what_the_script_fetched(mosquitto: Mosquitto, tmp_path: Path) -> None:
    binary = chromium()
    if binary is None:
        pytest.skip("no chromium: `make test` installs it (scripts/ensure-chromium.sh)")
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="16i")], base_port=0) as fleet, \
            RunningDaemon(fleet, mosquitto, tmp_path) as running:
        url = f"http://127.0.0.1:{running.http_port}/"
        await async_wait_for(lambda: rates_measured(running.http_port), 10, interval=0.1, message="poll rates")
        dom = await run_browser(binary, url, "--dump-dom")
        updates = re.search(r'data-updates="(\d+)"', dom)
        assert updates and int(updates.group(1)) >= 2, dom[:2000]  # the script ran and redrew the page twice
        assert "live, updated " in dom
        row = re.search(r'<tr id="machine-m1">(.*?)</tr>', dom, re.S)
        assert row is not None, dom[:2000]
        cells = re.findall(r"<td[^>]*>(.*?)</td>", row.group(1), re.S)
        assert cells[0] == "m1" and cells[1].startswith("connected since ") and cells[2] == "30i-BM"
        assert re.fullmatch(r"\d+\.\d\d / 4\.00 Hz", cells[3]), cells[3]  # a number, not "measuring"
        assert "Status/Run = " in cells[4] and "1001 SPINDLE OVERHEAT" in cells[5]
        m2 = re.search(r'<tr id="machine-m2">(.*?)</tr>', dom, re.S)
        assert m2 is not None and "ReadMacros" in m2.group(1)
        assert '<span id="broker" class="up">connected</span>' in dom
        assert '<dd id="identity-conflict" class="muted">none</dd>' in dom  # no other gateway with this identity
        if SCREENSHOT:
            await run_browser(binary, url, f"--screenshot={SCREENSHOT}", "--window-size=1400,640")
