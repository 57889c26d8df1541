"""`make run` acceptance: `python -m edge.cli.views.demo` reaches live data within a minute, with no broker (an embedded
amqtt broker starts) and with one (the suite's mosquitto), and Ctrl-C stops it cleanly. By default it shows the
compact view (a line per machine, a tail of events); `--raw` shows every message decoded."""

from __future__ import annotations

import asyncio
import re
import signal
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from tests.helpers import Mosquitto, async_wait_for, free_port, port_open

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
LIVE_DATA = re.compile(r"^DDATA  \S+/\S+ seq=\d+  \S+ = .+ @\d\d:\d\d:\d\d\.\d{3}$")
LIVE_JSON = re.compile(r"^JSON   focas/demo-plant/gateway-1/[\w-]+/state/\S+ = .* @\d\d:\d\d:\d\d\.\d{3}$")
# mill-1   30i-BM   connected  START  O1234  S 6140  parts 0  alarms: none
DEVICES = {"mill-1", "lathe-1", "lathe-1-path2", "mill-2"}  # the lathe's second path is a device of its own
MACHINE_LINE = re.compile(r"^(mill-1|lathe-1|lathe-1-path2|mill-2) +(\S+) +connected  (\S+)  O(\S+)  S (\S+)  "
                          r"parts (\S+)  alarms: ")
EMPTY_VALUE = re.compile(r"= ?$|=  ")  # a value printed as nothing


def demo_config(tmp_path: Path, broker_port: int) -> Path:
    """config/edge.yaml as shipped, pointed at `broker_port` and a private state dir."""
    text = (REPO / "config" / "edge.yaml").read_text()
    text, ports = re.subn(r"(?m)^  port: 1883$", f"  port: {broker_port}", text)
    text, dirs = re.subn(r"(?m)^state_dir: .*$", f"state_dir: {tmp_path / 'state'}", text)
    assert ports == 1 and dirs == 1, "config/edge.yaml changed shape: update this test"
    path = tmp_path / "edge.yaml"
    path.write_text(text)
    return path


class Demo:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.proc: asyncio.subprocess.Process | None = None
        self._reader: asyncio.Task[None] | None = None

    async def start(self, config: Path, *flags: str) -> None:
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "edge.cli.views.demo", "--duration", "90", "--config", str(config), *flags,
            cwd=REPO, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
        self._reader = asyncio.create_task(self._read())

    async def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        async for raw in self.proc.stdout:
            self.lines.append(raw.decode(errors="replace").rstrip("\n"))

    def matching(self, pattern: re.Pattern[str]) -> list[str]:
        return [line for line in list(self.lines) if pattern.match(line)]

    async def interrupt(self) -> int:
        """Ctrl-C, as a user would."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGINT)
        code = await asyncio.wait_for(self.proc.wait(), 20)
        if self._reader is not None:
            await asyncio.wait_for(self._reader, 5)
        return code

    async def kill(self) -> None:
        if self.proc is not None and self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        if self._reader is not None:
            self._reader.cancel()

    def text(self) -> str:
        return "\n".join(self.lines[-40:])


@pytest.fixture
async def demo() -> AsyncIterator[Demo]:
    running = Demo()
    yield running
    await running.kill()


async def reaches_live_data(demo: Demo) -> None:
    await async_wait_for(lambda: len(demo.matching(LIVE_DATA)) >= 5 and demo.matching(LIVE_JSON), 60,
                         message="decoded Sparkplug DDATA and JSON state lines")
    births = re.compile(r"^DBIRTH \S+/(\S+) ")
    await async_wait_for(lambda: {m.group(1) for line in demo.lines if (m := births.match(line))} == DEVICES, 30,
                         message="a DBIRTH for each simulated CNC and for the lathe's second path")
    profiles = {m.group(1) for line in demo.lines if (m := re.search(r"profile (\S+)", line))}
    assert profiles == {"30i", "31i-2p", "0i-F"}, "three different series, the lathe with two paths"


async def shows_the_compact_view(demo: Demo) -> None:
    """A line per machine with its state and values, and the births in the event tail."""
    await async_wait_for(lambda: {m.group(1) for line in demo.lines if (m := MACHINE_LINE.match(line))} ==
                         DEVICES, 60, message="a connected line for each machine and the lathe's second path")
    births = re.compile(r"^\d\d:\d\d:\d\d DBIRTH \S+/(\S+)")
    await async_wait_for(lambda: {m.group(1) for line in demo.lines if (m := births.match(line))} == DEVICES, 30,
                         message="a DBIRTH for each device in the event tail")
    series = {m.group(2) for line in demo.lines if (m := MACHINE_LINE.match(line))}
    assert series == {"30i-BM", "31i-BT", "0i-FM"}, series
    assert any(re.match(r"^== 4 of 4 machines connected, broker connected, \d+ messages received", line)
               for line in demo.lines), demo.text()
    assert not any(line.startswith(("DDATA", "JSON ")) for line in demo.lines), "no firehose by default"


async def test_demo_without_a_broker_starts_an_embedded_one(demo: Demo, tmp_path: Path) -> None:
    port = free_port()
    await demo.start(demo_config(tmp_path, port))
    await shows_the_compact_view(demo)
    assert any("starting an embedded broker (amqtt) there" in line for line in demo.lines), demo.text()
    assert any(f"-p {port}" in line and "mosquitto_sub" in line for line in demo.lines), "says where to subscribe"
    assert await demo.interrupt() == 0, demo.text()
    assert demo.lines[-1] == "== stopped cleanly", demo.text()
    assert not port_open("127.0.0.1", port), "the embedded broker stops with the demo"
    assert any("RAW=1" in line for line in demo.lines), "says where the firehose is"


async def test_demo_uses_a_broker_that_answers(demo: Demo, mosquitto: Mosquitto, tmp_path: Path) -> None:
    await demo.start(demo_config(tmp_path, mosquitto.port), "--raw")
    await reaches_live_data(demo)
    assert not [line for line in demo.lines if EMPTY_VALUE.search(line)], "empty values show as (none)"
    assert any(f"using the MQTT broker at 127.0.0.1:{mosquitto.port}" in line for line in demo.lines), demo.text()
    assert not any("embedded" in line for line in demo.lines)
    assert await demo.interrupt() == 0, demo.text()
    assert demo.lines[-1] == "== stopped cleanly", demo.text()
    assert mosquitto.running, "the demo leaves a broker it did not start alone"
    assert any(line.startswith("NDEATH") for line in demo.lines), "Ctrl-C ends the Sparkplug session cleanly"


async def test_a_second_demo_on_one_checkout_says_so_and_starts_nothing(demo: Demo, mosquitto: Mosquitto,
                                                                          tmp_path: Path) -> None:
    config = demo_config(tmp_path, mosquitto.port)
    await demo.start(config, "--raw")
    await reaches_live_data(demo)
    second = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "edge.cli.views.demo", "--duration", "30", "--config", str(config),
        cwd=REPO, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    out, _ = await asyncio.wait_for(second.communicate(), 30)
    assert second.returncode == 2, out.decode()
    lines = out.decode().splitlines()
    assert len(lines) == 1 and "is in use by another focas-edge" in lines[0], lines
    assert await demo.interrupt() == 0, demo.text()
