"""What an MES reads beyond status (issue 18), end to end: simulator over TCP, daemon, real mosquitto."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from edge.cli import main
from edge.config import parse_config
from edge.focas import items as it
from edge.focas.client import FocasClient
from edge.focas.errors import EW_PATH, CncError
from edge.focas.paths import path_count
from edge.focas.probe import probe
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, FleetThread, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration


def json_value(observer: Observer, topic: str) -> object:
    messages = observer.on(topic)
    return json.loads(messages[-1].payload)["value"] if messages else None


async def test_all_axes_numbers_are_published_per_axis_name(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """`axis: all`, an axis-0 number the control answers as an all-axes record (diag 308), and one it
    refuses with EW_ATTRIB at axis 0 (param 1825) are all published as <name>/<axis name>."""
    faults = {"ew": {"read_params/1825/0": 4}}
    async with Fleet([MachineSpec(profile="30i", faults=faults)], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, poll: {{periods: {{status: 0.1s, "
                    f"params: 0.2s, diags: 0.2s}}, params: [{{number: 1850, axis: all}}, 1825], diags: [308]}}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        state = fleet[0].state
        names = state.axis_names()
        try:
            for folder, number in (("Param", 1850), ("Param", 1825), ("Diag", 308)):
                for name in names:
                    await observer.wait_topic(f"focas/m1/state/{folder}/{number}/{name}", timeout=15)
            await async_wait_for(
                lambda: [json_value(observer, f"focas/m1/state/Param/1850/{n}") for n in names]
                == [float(state.read_param_value(1850, i + 1)) for i in range(len(names))],
                timeout=10, message="per-axis values of 1850")
            assert not observer.on("focas/m1/state/Param/1825"), "the refused axis-0 form is not published"
            assert not observer.on("focas/m1/state/Diag/308")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0


async def test_program_loads_times_and_part_totals_are_published(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """The running program's name and main path, servo load per axis name, the four plant timers in
    seconds, the part total/required counters, operator messages and tool offsets."""
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, "
                    f"poll: {{periods: {{status: 0.1s, loads: 0.2s, counters: 0.5s}}, tool_offsets: 2}}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        state = fleet[0].state
        try:
            topics = ["Program/Name", "Program/MainPath", "Times/PowerOn", "Times/Operating", "Times/Cutting",
                      "Times/Cycle", "Counters/PartsTotal", "Counters/PartsRequired", "Message/Operator",
                      "Tool/1/LengthGeometry", "Tool/2/RadiusWear",
                      *(f"Axis/{name}/Load" for name in state.axis_names())]
            for topic in topics:
                await observer.wait_topic(f"focas/m1/state/{topic}", timeout=15)
            assert json_value(observer, "focas/m1/state/Program/Name") == state.exec_program().name
            assert json_value(observer, "focas/m1/state/Program/MainPath") == state.main_program_path()
            assert json_value(observer, "focas/m1/state/Counters/PartsRequired") == state.read_param_value(6713, 0)
            assert json_value(observer, "focas/m1/state/Tool/2/RadiusWear") == state.tool_offsets(3, 2, 2)[0]
            messages = json.loads(str(json_value(observer, "focas/m1/state/Message/Operator")))
            assert isinstance(messages, list) and all(set(m) == {"number", "type", "text"} for m in messages)
            power_on = json_value(observer, "focas/m1/state/Times/PowerOn")
            assert isinstance(power_on, float) and power_on > 0
            birth = observer.of("DBIRTH")[-1].spb()
            names = {m.name for m in birth.metrics}
            assert set(topics) <= names
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0


async def test_a_two_path_lathe_answers_each_path_and_refuses_a_third() -> None:
    """Path discovery counts the paths before the first EW_PATH; a client on path 2 reads that path's own
    program; a single-path control has one path."""
    async with Fleet([MachineSpec(profile="31i-2p"), MachineSpec(profile="31i")], base_port=0) as fleet:
        lathe, single = fleet[0], fleet[1]
        second = lathe.state.for_path(2)
        assert second is not None and lathe.state.for_path(3) is None
        async with FocasClient("127.0.0.1", lathe.port, timeout=2) as cnc:
            assert await path_count(cnc) == 2
            (refused,) = await cnc.batch([it.ReadPathStatus(3)])
            assert isinstance(refused, CncError) and refused.code == EW_PATH
        async with FocasClient("127.0.0.1", lathe.port, timeout=2, path=2) as cnc2:
            numbers = await cnc2.read(it.ReadProgramNumber())
        assert numbers == second.program_numbers() != lathe.state.program_numbers()
        async with FocasClient("127.0.0.1", single.port, timeout=2) as cnc:
            assert await path_count(cnc) == 1
        report = await probe(FocasClient("127.0.0.1", lathe.port, timeout=2), "sim-31i-2p")
    assert report.paths == 2 and report.complete


def test_cli_reads_and_writes_name_their_path(capsys: pytest.CaptureFixture[str]) -> None:
    """`--path 2` reads path 2's program and writes path 2's macro; path 1 keeps its own."""
    with FleetThread(Fleet([MachineSpec(profile="31i-2p")], base_port=0)) as fleet:
        state = fleet[0].state
        second = state.for_path(2)
        assert second is not None
        address = f"127.0.0.1:{fleet[0].port}"
        assert main(["--log-level", "WARNING", "write", "--path", "2", address, "macro:510=7.5"]) == 0
        assert main(["--log-level", "WARNING", "read", "--json", "--path", "2", address, "program"]) == 0
        out = capsys.readouterr().out.splitlines()[-1]
    assert json.loads(out)["value"]["running"] == second.program_numbers().running
    assert second.read_macro(510) == 7.5 and state.read_macro(510) != 7.5


async def test_each_path_of_a_two_path_lathe_is_a_device_of_its_own(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """`paths: 2`: path 1 keeps the machine's device and topics, path 2 is device `<machine>-path2` with its
    own program, and a write to that device's command topic lands on path 2."""
    async with Fleet([MachineSpec(profile="31i-2p")], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, paths: 2, "
                    f"poll: {{periods: {{status: 0.1s}}}}}}\n")
        extra = "writes: {enabled: true, allow: [{target: 'macro:500-599'}]}\n"
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines, extra)))
        task = asyncio.create_task(daemon.run())
        state = fleet[0].state
        second = state.for_path(2)
        assert second is not None
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1-path2", timeout=15)
            await observer.wait_topic("focas/m1-path2/state/Program/Number", timeout=15)
            await observer.wait_topic("focas/m1/state/Program/Number", timeout=15)
            assert json_value(observer, "focas/m1-path2/state/Program/Number") == second.program_numbers().running
            assert json_value(observer, "focas/m1/state/Program/Number") == state.program_numbers().running
            await observer.publish("focas/m1-path2/cmd", json.dumps(
                {"id": "p2", "target": "macro:520", "value": 4.5}).encode())
            await observer.wait_topic("focas/m1-path2/cmd/reply", timeout=15)
            reply = json.loads(observer.on("focas/m1-path2/cmd/reply")[-1].payload)
            assert reply["ok"] is True, reply
            assert second.read_macro(520) == 4.5 and state.read_macro(520) != 4.5
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
