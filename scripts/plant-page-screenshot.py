#!/usr/bin/env python3
"""Screenshots of the plant page for the README: a demo-like fleet run for a few minutes, then Chromium.

    .venv/bin/python scripts/plant-page-screenshot.py [--seconds 240] [--out docs/images]

Three simulated CNCs as in `make run` (mill-1 with alarms that come and go, a 31i lathe, a 0i-F), a
mosquitto on a free port, the daemon with its status endpoint on; part way through mill-1 is held (feed
hold) for a while and mill-2 goes offline. Writes plant-machine.png (/machine/mill-1, the recent timeline
over the run) and plant-fleet.png (/). Needs mosquitto and chromium (scripts/ensure-*.sh).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim import CycleSpec, Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, mosquitto_binary, port_open
from tests.integration.test_status_page import chromium, run_browser


def config(broker: Mosquitto, state_dir: Path, fleet: Fleet, http_port: int) -> str:
    machines = "".join(f"  - {{id: {m.name}, host: 127.0.0.1, port: {m.port}, timezone: Europe/Berlin, "
                       "timeouts: {request_s: 1, connect_s: 1, backoff_initial_s: 0.2, backoff_max_s: 1}}\n"
                       for m in fleet.machines)
    return (f"mqtt: {{host: {broker.host}, port: {broker.port}, formats: [sparkplug], "
            f"sparkplug: {{group_id: plant, edge_node_id: gw}}}}\nstate_dir: {state_dir}\n"
            f"http: {{enabled: true, host: 127.0.0.1, port: {http_port}}}\nmachines:\n{machines}")


async def main(seconds: float, out: Path) -> int:
    binary, broker_binary = chromium(), mosquitto_binary()
    if binary is None or broker_binary is None:
        print("needs chromium and mosquitto (scripts/ensure-chromium.sh, scripts/ensure-mosquitto.sh)")
        return 1
    specs = [MachineSpec(name="mill-1", profile="30i", timezone="Europe/Berlin",
                         cycle=CycleSpec(cut_seconds=14, idle_seconds=5, alarm_every=3, alarm_seconds=8)),
             MachineSpec(name="lathe-1", profile="31i", timezone="Europe/Berlin",
                         cycle=CycleSpec(cut_seconds=20, idle_seconds=8, alarm_every=0)),
             MachineSpec(name="mill-2", profile="0i-F", timezone="Europe/Berlin",
                         cycle=CycleSpec(cut_seconds=9, idle_seconds=12, alarm_every=4, alarm_seconds=5))]
    broker = Mosquitto(broker_binary)
    broker.start()
    http_port = free_port()
    try:
        with tempfile.TemporaryDirectory(prefix="plant-page-") as state_dir:
            async with Fleet(specs, base_port=0) as fleet:
                daemon = Daemon(parse_config(config(broker, Path(state_dir), fleet, http_port)))
                task = asyncio.create_task(daemon.run())
                try:
                    await async_wait_for(lambda: port_open("127.0.0.1", http_port), 10, message="status endpoint")
                    await asyncio.sleep(seconds * 0.35)
                    fleet[0].state.set_feed_hold(True)
                    await asyncio.sleep(seconds * 0.15)
                    fleet[0].state.set_feed_hold(False)
                    await asyncio.sleep(seconds * 0.3)
                    fleet[2].faults.update({"refuse": -1})
                    fleet[2].drop_connections()
                    await asyncio.sleep(seconds * 0.2)
                    minutes = max(1, min(60, round(seconds / 60 + 0.5)))
                    base = f"http://127.0.0.1:{http_port}"
                    await run_browser(binary, f"{base}/machine/mill-1?minutes={minutes}",
                                      f"--screenshot={out / 'plant-machine.png'}", "--window-size=1100,820",
                                      "--virtual-time-budget=1000")
                    await run_browser(binary, f"{base}/", f"--screenshot={out / 'plant-fleet.png'}",
                                      "--window-size=1100,470", "--virtual-time-budget=1000")
                finally:
                    daemon.request_stop()
                    await asyncio.wait_for(task, 20)
    finally:
        broker.stop()
    print(f"wrote {out / 'plant-machine.png'} and {out / 'plant-fleet.png'}")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=240.0, help="how long the fleet runs first")
    parser.add_argument("--out", type=Path, default=Path("docs/images"), help="directory for the PNGs")
    args = parser.parse_args()
    sys.exit(asyncio.run(main(args.seconds, args.out)))
