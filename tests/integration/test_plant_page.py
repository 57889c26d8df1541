"""The plant page in headless Chromium: a simulated 30i driven over the simulator's admin endpoint through
run -> feed hold -> alarm -> offline shows those bands, in that order, with widths in proportion to how long
each lasted; the fleet overview puts the offline machine first. Real daemon, real mosquitto, real TCP."""

from __future__ import annotations

import asyncio
import json
import os
import re
import time
import urllib.request
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.admin import AdminServer
from edge.sim.fleet import Fleet, MachineSpec
from edge.sim.state_program import CycleSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, port_open
from tests.integration.test_status_http import config_text, http_get
from tests.integration.test_status_page import chromium, run_browser

pytestmark = pytest.mark.integration

# Set to a PNG path to keep a screenshot of the machine page at the end of the scenario (docs/images).
SCREENSHOT = os.environ.get("PLANT_PAGE_SCREENSHOT", "")
# How long the scenario holds each state (seconds): the durations under test, not synchronisation (every
# change is awaited on the page's own state).
HOLD_S = {"running": 5.0, "feed-hold": 3.0, "alarm": 4.0, "offline": 2.0}
ZOOM_MINUTES = 1  # the recent timeline spans 60 s, so a 3 s band is 50 units of 1000
TOLERANCE_S = 1.0  # a status tick is 0.25 s; an offline is seen at the next failed request


def post(admin: AdminServer, path: str, body: dict[str, object]) -> None:
    request = urllib.request.Request(admin.url + path, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=5) as response:
        response.read()


async def page_state(http_port: int, machine_id: str) -> str:
    status, _, body = await http_get(http_port, f"/machine/{machine_id}")
    found = re.search(r'<body data-machine="[^"]*" data-state="([a-z-]+)"', body.decode())
    return found.group(1) if status == 200 and found else ""


async def enter(http_port: int, state: str) -> float:
    """Wait until the page shows m1 in `state`; when it was first seen so (gateway time)."""
    await async_wait_for(lambda: _is(http_port, state), 15, interval=0.05, message=f"m1 {state} on the page")
    return time.time()


async def _is(http_port: int, state: str) -> bool:
    return await page_state(http_port, "m1") == state


async def test_chromium_shows_run_feed_hold_alarm_offline_in_order_with_proportional_widths(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    binary = chromium()
    if binary is None:
        pytest.skip("no chromium: `make test` installs it (scripts/ensure-chromium.sh)")
    cutting_all_along = CycleSpec(cut_seconds=3600.0, idle_seconds=5.0, alarm_every=0)
    # seed 1 puts m1 7.3 s into its part: past the M06 at the start (a WAIT, drawn as idle), cutting throughout
    specs = [MachineSpec(profile="30i", cycle=cutting_all_along, seed=1), MachineSpec(profile="16i", seed=2)]
    http_port = free_port()
    async with Fleet(specs, base_port=0) as fleet, AdminServer(fleet) as admin:
        daemon = Daemon(parse_config(config_text(mosquitto, tmp_path, [fleet[0].port, fleet[1].port], http_port,
                                                 0.5)))
        task = asyncio.create_task(daemon.run())
        try:
            await async_wait_for(lambda: port_open("127.0.0.1", http_port), 10, message="status endpoint")
            changes = {"running": await enter(http_port, "running")}
            await asyncio.sleep(HOLD_S["running"])
            await asyncio.to_thread(post, admin, "/machines/0/state", {"feed_hold": True})
            changes["feed-hold"] = await enter(http_port, "feed-hold")
            await asyncio.sleep(HOLD_S["feed-hold"])
            await asyncio.to_thread(post, admin, "/machines/0/state",
                                    {"raise_alarm": {"number": 1004, "type": "EX", "message": "COOLANT LEVEL LOW"}})
            changes["alarm"] = await enter(http_port, "alarm")
            await asyncio.sleep(HOLD_S["alarm"])
            await asyncio.to_thread(post, admin, "/machines/0/faults", {"refuse": -1, "drop_now": True})
            changes["offline"] = await enter(http_port, "offline")
            await asyncio.sleep(HOLD_S["offline"])

            url = f"http://127.0.0.1:{http_port}/machine/m1?minutes={ZOOM_MINUTES}"
            dom = await run_browser(binary, url, "--dump-dom", "--virtual-time-budget=1000")
            rendered_at = time.time()
            recent = re.search(r'<svg id="timeline-hour"[^>]*data-start="([\d.]+)" data-end="([\d.]+)"(.*?)</svg>',
                               dom, re.S)
            assert recent is not None, dom[:3000]
            start, end = float(recent.group(1)), float(recent.group(2))
            assert 59.9 < end - start < 60.1
            bands = [(css, float(x), float(width), float(b), float(e)) for css, x, width, b, e in re.findall(
                r'<rect class="band ([a-z-]+)" x="([\d.]+)" y="0" width="([\d.]+)" height="\d+" '
                r'data-start="([\d.]+)" data-end="([\d.]+)"', recent.group(3))]
            assert [b[0] for b in bands if b[0] != "unknown"] == ["running", "feed-hold", "alarm", "offline"], bands
            assert all(b[0] == "unknown" for b in bands[:-4]), bands  # only before the first status read
            order = ["running", "feed-hold", "alarm", "offline"]
            seen_until = [changes[s] for s in order[1:]] + [rendered_at]
            for (css, x, width, begin, until), state, seen_end in zip(bands[-4:], order, seen_until, strict=True):
                assert css == state
                expected = seen_end - changes[state]
                assert abs((until - begin) - expected) <= TOLERANCE_S + (0.5 if state == "offline" else 0), \
                    (state, until - begin, expected)
                assert abs(width - (until - begin) / 60.0 * 1000) < 0.05  # width in proportion to its duration
                assert abs(x - (begin - start) / 60.0 * 1000) < 0.05  # data-* are rounded to ms
            held = {css: until - begin for css, _, _, begin, until in bands[-4:-1]}
            for state in ("running", "feed-hold", "alarm"):
                assert held[state] >= HOLD_S[state] - TOLERANCE_S, (state, held)
            assert 'data-state="offline"' in dom and "COOLANT LEVEL LOW" in dom and "raised" in dom
            assert re.search(r'<svg id="spark-Feed-Actual" class="spark"[^>]*><(polyline|circle) ', dom)

            overview = await run_browser(binary, f"http://127.0.0.1:{http_port}/", "--dump-dom",
                                         "--virtual-time-budget=1000")
            rows = re.findall(r'<tr id="fleet-(m\d)" data-state="([a-z-]+)"', overview)
            assert rows[0] == ("m1", "offline") and rows[1][0] == "m2", rows  # trouble first
            assert rows[1][1] in ("running", "idle", "alarm"), rows
            if SCREENSHOT:
                await run_browser(binary, url, f"--screenshot={SCREENSHOT}", "--window-size=1200,900",
                                  "--virtual-time-budget=1000")
        finally:
            daemon.request_stop()
            await asyncio.wait_for(task, 20)
