"""Per-function routing end to end: one machine, native FOCAS/Ethernet plus a library host (fwlib_host).

The simulator's packed server stands in for `focas-edge fwlib-host` (same surface, same machine state):
fast polls must stay on the native connection, while the alarm history and parameter writes go to the
library host. Its request log shows which functions reached it.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from pathlib import Path

import pytest

from edge.cli import EXIT_OK, main
from edge.config import parse_config
from edge.focas import packed as pk
from edge.focas.model import SysInfo
from edge.focas.packed.endpoint import start_packed_endpoint
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, FleetThread, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer, metrics_by_name

pytestmark = pytest.mark.integration

TIMEOUTS = "timeouts: {request_s: 1, connect_s: 1, backoff_initial_s: 0.05, backoff_max_s: 0.3}"
EXTRA = """
alarms: {mode: ActivePlusHistory, history_interval: 0.5s}
writes:
  enabled: true
  allow:
    - {target: 'param:1825'}
"""


async def native_ddata_flows(observer: Observer) -> None:
    """Wait for a few more DDATA from m1: its native polls go on."""
    data = len(observer.on("spBv1.0/plant/DDATA/gw/m1"))
    await async_wait_for(lambda: len(observer.on("spBv1.0/plant/DDATA/gw/m1")) > data + 3,
                         timeout=15, message="native polls going on")


async def test_history_and_parameter_writes_go_to_the_library_host_fast_polls_stay_native(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i", param_write_enabled=True)], base_port=0,
                     packed_base_port=0) as fleet:
        sim = fleet[0]
        ring = len(sim.state.alarm_events())
        machine = (f"  - {{id: m1, host: 127.0.0.1, port: {sim.port}, "
                   f"fwlib_host: 'tcp:127.0.0.1:{sim.packed_port}', {TIMEOUTS}, "
                   f"poll: {{periods: {{status: 0.25, params: 0.5}}, params: [{{number: 1825, axis: 1}}]}}}}\n")
        config = parse_config(daemon_config(mosquitto, tmp_path, machine, EXTRA))
        assert config.warnings == []
        daemon = Daemon(config)
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)

            def history() -> list[object]:
                docs = [json.loads(m.payload) for m in observer.on("focas/m1/events/alarm")]
                return [d for d in docs if d["name"] == "Alarm/History"]

            await async_wait_for(lambda: len(history()) >= ring, timeout=15, message="history via the library host")

            await observer.publish("focas/m1/cmd", json.dumps({"target": "param:1825/1", "value": 2700}).encode())
            [reply] = await observer.wait_topic("focas/m1/cmd/reply", count=1, timeout=15)
            assert json.loads(reply.payload)["value_read_back"] == 2700, reply.payload
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0

        packed_commands = {r.command for r in sim.packed.requests}
        assert pk.Command.RDALMHISTRY in packed_commands
        assert pk.Command.WRPARAM in packed_commands
        # Nothing the native side has went to the library host: no status, clock, parameter read, alarm poll.
        assert packed_commands <= {pk.Command.SYSINFO, pk.Command.RDALMHISTRY, pk.Command.WRPARAM}
        assert [w.protocol for w in sim.state.writes("param:1825")] == ["packed"]
        birth = metrics_by_name(observer.on("spBv1.0/plant/DBIRTH/gw/m1")[0].spb())
        assert "ReadAlarmHistory" not in birth["Plan/DroppedFunctions"].string_value


async def test_without_a_library_host_the_history_read_is_listed_as_dropped(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        machine = f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, {TIMEOUTS}}}\n"
        config = parse_config(daemon_config(mosquitto, tmp_path, machine, EXTRA))
        assert any("ActivePlusHistory on the native transport alone" in w for w in config.warnings)
        daemon = Daemon(config)
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0
    birth = metrics_by_name(observer.on("spBv1.0/plant/DBIRTH/gw/m1")[0].spb())
    assert "ReadAlarmHistory" in birth["Plan/DroppedFunctions"].string_value.split(",")


def test_probe_shows_which_transport_answers_each_function(capsys: pytest.CaptureFixture[str]) -> None:
    with FleetThread(Fleet([MachineSpec(profile="30i")], base_port=0, packed_base_port=0)) as fleet:
        args = ["probe", f"127.0.0.1:{fleet[0].port}", "--fwlib-host", f"tcp:127.0.0.1:{fleet[0].packed_port}",
                "--timeout", "2"]
        assert main([*args, "--json"]) == EXIT_OK
        doc = json.loads(capsys.readouterr().out)
        assert main(args) == EXIT_OK
        table = capsys.readouterr().out
    functions = {f["function"]: f for f in doc["functions"]}
    assert functions["ReadAlarmHistory"]["via"] == "fwlib-host"
    assert functions["ReadAlarmHistory"]["outcome"] == "ok"
    assert functions["ReadStatus"]["via"] == "native" and functions["ReadSpindleLoad"]["via"] == "native"
    writes = {w["operation"]: w for w in doc["writes"]}
    assert writes["write_param"]["via"] == "fwlib-host" and writes["write_param"]["transport_has_it"]
    assert writes["write_macro"]["via"] == "native"
    history = [line for line in table.splitlines() if line.strip().startswith("ReadAlarmHistory")]
    assert history and "[fwlib-host]" in history[0]
    for library_only in ("ReadWorkOffsets", "ReadModalGCodes", "ReadToolNumber"):
        assert functions[library_only]["via"] == "fwlib-host" and functions[library_only]["outcome"] == "ok"


async def test_library_only_data_comes_from_the_library_host_while_fast_polls_stay_native(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0, packed_base_port=0) as fleet:
        sim = fleet[0]
        axes = sim.state.axis_names()
        machine = (f"  - {{id: m1, host: 127.0.0.1, port: {sim.port}, "
                   f"fwlib_host: 'tcp:127.0.0.1:{sim.packed_port}', {TIMEOUTS}, "
                   "poll: {periods: {status: 0.25}, work_offsets: [54, 55], modal: true, tool_number: true}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machine)))
        task = asyncio.create_task(daemon.run())
        try:
            for g_code, number in ((54, 1), (55, 2)):
                for axis, value in zip(axes, sim.state.work_offsets(number), strict=True):
                    [doc, *_] = await observer.wait_topic(f"focas/m1/state/WorkOffset/G{g_code}/{axis}", timeout=15)
                    assert json.loads(doc.payload)["value"] == value
            [modal, *_] = await observer.wait_topic("focas/m1/state/Modal/G", timeout=15)
            assert json.loads(json.loads(modal.payload)["value"])["13"] == "G54"
            [tool, *_] = await observer.wait_topic("focas/m1/state/Tool/Number", timeout=15)
            assert json.loads(tool.payload)["value"] in range(1, 5)
            await native_ddata_flows(observer)
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0
        # The library host saw its identity read and the library-only reads: every fast poll stayed native.
        assert {r.command for r in sim.packed.requests} == {pk.Command.SYSINFO, pk.Command.RDZOFS,
                                                            pk.Command.RDGCODE, pk.Command.RDTOOLNUM}
        assert {pk.decode_i16_request(r.payload, "rdzofs") for r in sim.packed.requests_for(pk.Command.RDZOFS)} \
            == {1, 2}
    birth = metrics_by_name(observer.on("spBv1.0/plant/DBIRTH/gw/m1")[0].spb())
    assert {f"WorkOffset/G54/{axis}" for axis in axes} <= set(birth)
    dropped = birth["Plan/DroppedFunctions"].string_value
    assert not {"ReadWorkOffsets", "ReadModalGCodes", "ReadToolNumber"} & set(dropped.split(","))
    assert {"Modal/G", "Tool/Number"} <= set(birth)


async def native_polls_go_on(mosquitto: Mosquitto, observer: Observer, tmp_path: Path, fwlib_host: str,
                             library_tried: Callable[[], bool]) -> None:
    """Run the daemon on a native machine with this library host until the host was tried and the native
    polls went on; then the machine was born once and never reset (no DDEATH before shutdown)."""
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        machine = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, fwlib_host: '{fwlib_host}', "
                   f"{TIMEOUTS}, poll: {{periods: {{status: 0.25}}}}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machine, EXTRA)))
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            await async_wait_for(library_tried, timeout=15, message="the library host tried (again)")
            await native_ddata_flows(observer)
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 15) == 0
    assert observer.on("spBv1.0/plant/DDEATH/gw/m1")[:-1] == []  # only the one at shutdown, if any
    assert len(observer.on("spBv1.0/plant/DBIRTH/gw/m1")) == 1


async def test_a_silent_library_host_never_holds_up_or_resets_the_native_polls(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    accepted: list[asyncio.StreamWriter] = []

    async def silent(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        accepted.append(writer)  # accepts, reads nothing, answers nothing: a hung library host

    silent_host = await asyncio.start_server(silent, "127.0.0.1", 0)
    port = silent_host.sockets[0].getsockname()[1]
    try:
        await native_polls_go_on(mosquitto, observer, tmp_path, f"tcp:127.0.0.1:{port}",
                                 lambda: len(accepted) >= 2)  # connect retried in the background
    finally:
        for writer in accepted:
            writer.close()
        silent_host.close()
        await silent_host.wait_closed()


async def test_a_library_host_that_stops_answering_fails_its_items_not_the_native_session(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    never = asyncio.Event()

    async def answers_only_sysinfo(command: int, payload: bytes) -> bytes:
        if command == pk.Command.SYSINFO:
            return pk.read_response(pk.encode_sysinfo(SysInfo(0, 8, "31", " M", "G421", "0013", "03")))
        await never.wait()  # a hung library host: connected, then silent
        return b""

    host = await start_packed_endpoint(answers_only_sysinfo)
    try:
        await native_polls_go_on(mosquitto, observer, tmp_path, host.address,
                                 lambda: len(host.requests_for(pk.Command.RDALMHISTRY)) >= 2)
    finally:
        never.set()
        await host.close()
