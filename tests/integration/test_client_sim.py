"""Our FOCAS client against the simulated CNC over real TCP, on every profile."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import urllib.request
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from edge.focas import functions as fn
from edge.focas import items as it
from edge.focas.client import FocasClient
from edge.focas.errors import EW_FUNC, FocasError, LengthError, OutOfRange
from edge.focas.frame import Frame, FrameDecoder, decode_response_body, encode_open_request, encode_request
from edge.focas.model import DIAG_TYPE_CODES, ParamType, PmcType
from edge.sim.fleet import Fleet, MachineSpec
from edge.sim.profiles import PROFILES
from edge.sim.state_program import CycleSpec
from tests.helpers import wait_for

pytestmark = pytest.mark.integration

T0 = 1_750_000_000.25  # a quarter second past a whole second: no timer is an exact minute


class FakeClock:
    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(params=sorted(PROFILES))
async def sim(request: pytest.FixtureRequest) -> AsyncIterator[tuple[Fleet, FakeClock]]:
    """One machine of each profile (one per test run), frozen in mid-cut with an active alarm."""
    clock = FakeClock()
    spec = MachineSpec(profile=request.param, timezone="Europe/Berlin", clock_offset=42.0,
                       cycle=CycleSpec(cut_seconds=10.0, idle_seconds=5.0), seed=0)
    fleet = Fleet([spec], base_port=0, time_source=clock)
    clock.now += 3.3  # cutting
    fleet[0].state.raise_alarm(1004, 15, 0, "COOLANT LEVEL LOW")
    async with fleet:
        yield fleet, clock


def client(fleet: Fleet, timeout: float = 2.0) -> FocasClient:
    return FocasClient("127.0.0.1", fleet[0].port, timeout=timeout, connect_timeout=timeout)


def every_item() -> list[it.ReadItem]:
    return [
        it.ReadSysInfo(), it.ReadStatus(), it.ReadAlarmStatus(), it.ReadActiveAlarms(),
        it.ReadProgramNumber(), it.ReadSequenceNumber(), it.ReadExecProgramName(), it.ReadMainProgramPath(),
        it.ReadProgramDirectory(), it.ReadFeed(), it.ReadSpindleSpeed(), it.ReadSpindleLoad(),
        *(it.ReadPositions(kind) for kind in it.POSITION_KINDS), it.ReadAxisNames(), it.ReadSpindleNames(),
        it.ReadServoMeter(), it.ReadControlledAxes(), it.ReadParams(0, 9999, -1), it.ReadParams(1420, 1420, 2),
        it.ReadDiag(0, 9999, -1), it.ReadMacros(100, 199), it.ReadMacros(500, 999),
        it.ReadPmc("D", 2204, 2205, PmcType.WORD), it.ReadPmc("G", 0, 31), it.ReadPmc("R", 100, 107, PmcType.LONG),
        it.ReadClock(), *(it.ReadTimer(kind) for kind in range(5)),
        *(it.ReadToolOffsets(kind, 3, 4) for kind in range(4)), it.ReadOperatorMessages(),
    ]


def expected_values(fleet: Fleet) -> list[object]:
    s = fleet[0].state
    return [
        s.sysinfo(), s.status(), s.alarm_status(), s.active_alarms(10),
        s.program_numbers(), s.sequence_number(), s.exec_program(), s.main_program_path(),
        s.program_directory(1, 19), s.actual_feed(), s.spindle_speed(), s.spindle_loads(),
        *(s.positions(kind) for kind in it.POSITION_KINDS), s.axis_names(), s.spindle_names(),
        s.servo_meter(), s.profile.axis_count, s.read_params(0, 9999, -1), s.read_params(1420, 1420, 2),
        s.read_diag(0, 9999, -1), s.read_macros(100, 199), s.read_macros(500, 999),
        [600], s.read_pmc("G", 0, 31), s.read_pmc("R", 100, 107, PmcType.LONG),
        s.clock().replace(microsecond=0), *(s.timer(kind) for kind in range(5)),
        *(s.tool_offsets(kind, 3, 6) for kind in range(4)), s.operator_messages(),
    ]


def same_records(got: Any, want: Any, diag: bool = False) -> bool:
    """Records match when number, axis, type and the state's values agree (the wire pads to max_axis);
    diagnosis records carry the diagnosis type codes on the wire."""
    if len(got) != len(want):
        return False
    for a, b in zip(got, want, strict=True):
        n = len(b.values)
        wire_type = DIAG_TYPE_CODES[ParamType(b.type)] if diag else b.type
        if (a.number, a.axis, a.type, a.values[:n]) != (b.number, b.axis, wire_type, b.values):
            return False
    return True


async def test_every_function_on_every_profile(sim: tuple[Fleet, FakeClock]) -> None:
    fleet, _ = sim
    async with client(fleet) as cnc:
        assert cnc.sysinfo == fleet[0].state.sysinfo()
        items = every_item()
        results = await cnc.batch(items)
    for item, got, want in zip(items, results, expected_values(fleet), strict=True):
        assert not isinstance(got, FocasError), f"{item}: {got}"
        if isinstance(item, it.ReadParams | it.ReadDiag):
            assert same_records(got, want, isinstance(item, it.ReadDiag)), f"{item}: {got} != {want}"
        else:
            assert got == want, f"{item}: {got!r} != {want!r}"
    assert results[2] == 1 << 15 and results[3][0].message == "COOLANT LEVEL LOW"


async def test_diagnosis_records_carry_real_type_codes_and_whole_values(sim: tuple[Fleet, FakeClock]) -> None:
    """Type 2 for a 2-word diagnosis (160i-W capture), 0 for a byte one (31i capture); a word value
    (spindle speed, above 255) is not cut to a byte because its type code is 1."""
    fleet, _ = sim
    state = fleet[0].state
    async with client(fleet) as cnc:
        speed, temperature, position = await cnc.batch(
            [it.ReadDiag(411, 411), it.ReadDiag(308, 308, 1), it.ReadDiag(980, 980, 1)])
    assert speed[0].type == 1 and speed[0].value == state.read_diag(411, 411)[0].value > 255
    assert temperature[0].type == 0 and temperature[0].value == state.read_diag(308, 308, 1)[0].value
    assert position[0].type == 2 and position[0].value == state.read_diag(980, 980, 1)[0].value


async def test_a_batch_of_ten_items_is_one_request_pdu(sim: tuple[Fleet, FakeClock]) -> None:
    fleet, _ = sim
    async with client(fleet) as cnc:
        before = fleet[0].requests
        items = every_item()[:10]
        results = await cnc.batch(items)
        assert fleet[0].requests - before == 1
        assert fleet[0].native.stats.last_batch == 10
        assert not any(isinstance(r, FocasError) for r in results)


async def test_an_item_that_errors_does_not_fail_the_batch(sim: tuple[Fleet, FakeClock]) -> None:
    fleet, _ = sim
    items = [it.ReadMacros(500, 501), it.ReadMacros(300, 301), it.ReadPmc("R", 7999, 8000),
             it.ReadParams(2, 3), it.ReadStatus()]
    async with client(fleet) as cnc:
        before = fleet[0].requests
        results = await cnc.batch(items)
        assert fleet[0].requests - before == 1
    assert results[0] == [12.5, 0.0]
    assert isinstance(results[1], OutOfRange) and results[1].code == 3
    assert isinstance(results[2], OutOfRange) and results[3].code == 3
    assert results[4] == fleet[0].state.status()


async def test_the_other_record_form_answers_ew_func(sim: tuple[Fleet, FakeClock]) -> None:
    """Raw subpackets over TCP: the parameter/diag form the profile does not have gives EW_FUNC."""
    fleet, _ = sim
    wide = fleet[0].state.profile.wide_records
    reader, writer = await asyncio.open_connection("127.0.0.1", fleet[0].port)
    try:
        decoder = FrameDecoder()

        async def exchange(data: bytes) -> list[Frame]:
            writer.write(data)
            frames: list[Frame] = []
            while not frames:
                frames = decoder.feed(await asyncio.wait_for(reader.read(65536), 5))
            return frames

        await exchange(encode_open_request())
        requests = [f.request(6711, 6711, 0) for f in (fn.READ_PARAMS_4, fn.READ_PARAMS_8)]
        requests += [f.request(980, 980, 1) for f in (fn.READ_DIAG_4, fn.READ_DIAG_8)]
        (frame,) = await exchange(encode_request(requests))
        assert frame.version == fleet[0].state.profile.response_version
        answers = decode_response_body(frame.body)
        rcs = [a.rc for a in answers]
        assert rcs == ([EW_FUNC, 0, EW_FUNC, 0] if wide else [0, EW_FUNC, 0, EW_FUNC])
    finally:
        writer.close()
        await writer.wait_closed()


async def test_writes_reach_the_machine(sim: tuple[Fleet, FakeClock]) -> None:
    fleet, _ = sim
    state = fleet[0].state
    async with client(fleet) as cnc:
        await cnc.write_macro(500, 12.345)
        await cnc.write_macro(150, -0.001)
        assert await cnc.read_macros(500) == [12.345]
        assert state.read_macro(150) == -0.001
        await cnc.write_pmc("R", 1000, bytes(range(70)))
        assert state.read_pmc_bytes("R", 1000, 1069) == bytes(range(70))
        assert [w.target for w in state.writes("pmc:")] == ["pmc:R1000-R1031", "pmc:R1032-R1063",
                                                           "pmc:R1064-R1069"]
        await cnc.write_pmc_bit("R", 2000, 3, True)
        await cnc.write_pmc_bit("R", 2000, 6, True)
        assert state.read_pmc_bytes("R", 2000, 2000) == bytes([0b0100_1000])
        with pytest.raises(LengthError) as too_long:
            await cnc._locked_write(cnc._write_pmc_bytes("R", 0, bytes(33)))
        assert too_long.value.code == 2
        with pytest.raises(OutOfRange):
            await cnc.write_pmc("X", 127, b"\x01\x02")
        await cnc.set_clock(state.clock().replace(hour=6, minute=30, second=0, microsecond=0))
        assert (await cnc.read_clock()).time().isoformat() == "06:30:00"
        assert await cnc.read_status() == state.status()  # still a working session
    assert all(w.protocol == "native" for w in state.write_log)


async def test_the_machine_moves_between_reads(sim: tuple[Fleet, FakeClock]) -> None:
    fleet, clock = sim
    async with client(fleet) as cnc:
        parts = int((await cnc.read_params(6711))[0].value or 0)
        first = await cnc.batch([it.ReadPositions("absolute"), it.ReadStatus()])
        clock.now += 0.7
        second = await cnc.batch([it.ReadPositions("absolute"), it.ReadStatus()])
        assert first[0] != second[0] and second[1].run == 3
        clock.now += 8.0  # between parts
        idle = await cnc.read_status()
        assert (idle.run, idle.motion) == (0, 0)
        assert (await cnc.read_params(6711))[0].value == parts + 1


def test_cli_sim_runs_until_sigterm(tmp_path: Path) -> None:
    """`focas-edge sim` prints its ports, serves them (admin endpoint included) and stops on SIGTERM."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "edge", "--log-level", "WARNING", "sim", "--machines", "2", "--port", "0",
         "--profile", "16i,30i", "--admin-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=Path(__file__).parents[2],
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        stdout = proc.stdout
        assert stdout is not None
        lines: list[str] = []

        def ready() -> bool:
            lines.append(stdout.readline())
            return lines[-1].startswith("ready") or proc.poll() is not None

        wait_for(ready, timeout=20, message="the simulator to print 'ready'")
        text = "".join(lines)
        ports = [int(p) for p in re.findall(r"focas 127\.0\.0\.1:(\d+)", text)]
        admin = re.search(r"admin\s+(http://\S+)", text)
        assert len(ports) == 2 and admin, text
        with urllib.request.urlopen(admin.group(1), timeout=5) as response:
            machines = json.load(response)
        assert [m["profile"] for m in machines] == ["16i", "30i"]
        assert [m["port"] for m in machines] == ports

        async def probe() -> str:
            async with FocasClient("127.0.0.1", ports[1], timeout=5) as cnc:
                return (await cnc.read_sysinfo()).cnc_type

        assert asyncio.run(probe()) == "30"
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=15)
    assert code == 0
