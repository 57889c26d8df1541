"""`focas-edge read` / `write` against the simulated CNC over real TCP (native and packed transports)."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from edge.cli import main
from edge.cli.named_reads import NAMED_READS, TIMER_KINDS
from edge.focas.items import TOOL_OFFSET_KINDS
from edge.focas.targets import READ_NAMES
from edge.sim.native_server import NativeServer
from edge.sim.packed_server import PackedServer, start_packed_server
from edge.sim.state import MachineState
from tests.helpers import free_port

pytestmark = pytest.mark.integration
REPO = Path(__file__).resolve().parents[2]


@dataclass
class Sim:
    state: MachineState
    native: NativeServer
    packed: PackedServer
    loop: asyncio.AbstractEventLoop

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.native.port}"


@pytest.fixture(scope="module")
def sim() -> Iterator[Sim]:
    """One simulated 30i serving both transports from an event loop in its own thread."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="sim-loop", daemon=True)
    thread.start()

    def call(coro: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout=10)

    state = MachineState("30i", name="cli-test")
    native = NativeServer(state)
    call(native.start())
    packed = call(start_packed_server(state))
    try:
        yield Sim(state, native, packed, loop)
    finally:
        call(native.close())
        call(packed.close())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=10)
        loop.close()


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["--log-level", "WARNING", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def json_lines(out: str) -> dict[str, dict[str, Any]]:
    rows = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert all({"item", "value", "error"} <= set(row) <= {"item", "value", "error", "refused"} for row in rows)
    return {row["item"]: row for row in rows}


ALL_ITEMS = ("sysinfo", "status", "alarms", "program", "positions", "clock", "macro:500-505", "param:6711",
             "param:1815/1", "diag:980-981/1", "pmc:D2204.word", "pmc:R100-R103")


def test_read_every_item_kind_as_json(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "read", "--json", sim.address, *ALL_ITEMS)
    assert code == 0, err
    rows = json_lines(out)
    assert list(rows) == list(ALL_ITEMS)
    assert all(row["error"] is None for row in rows.values())
    assert rows["sysinfo"]["value"]["cnc_type"].strip() == "30"
    macros = rows["macro:500-505"]["value"]
    assert list(macros) == [f"#{n}" for n in range(500, 506)]
    assert macros["#500"] == sim.state.read_macro(500)
    assert isinstance(rows["param:6711"]["value"], int)  # the part count moves while the cycle runs
    assert rows["param:1815/1"]["value"] == sim.state.read_param_value(1815, 1)
    assert rows["pmc:D2204.word"]["value"] == sim.state.read_pmc("D", 2204, 2205, 1)[0]
    assert list(rows["pmc:R100-R103"]["value"]) == ["R100", "R101", "R102", "R103"]
    assert set(rows["positions"]["value"]) == set(sim.state.axis_names())
    assert set(rows["diag:980-981/1"]["value"]) == {"980", "981"}
    assert rows["clock"]["value"][:4].isdigit()


# No public native wire form: only the library host (packed surface) serves these.
LIBRARY_ONLY_READS = {"work_offsets", "modal", "tool_number"}


def test_every_named_read_offers_what_the_client_reads(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    """Loads, names, timers, program name/path/directory: every client function, one JSON shape."""
    native_reads = [name for name in NAMED_READS if name not in LIBRARY_ONLY_READS]
    code, out, err = run_cli(capsys, "read", "--json", sim.address, *native_reads)
    assert code == 0, err
    rows = json_lines(out)
    assert set(rows) == set(native_reads) and all(row["error"] is None for row in rows.values())
    state = sim.state
    axes, spindles = state.axis_names(), state.spindle_names()
    loads = rows["loads"]["value"]
    assert list(loads["servo"]) == axes and list(loads["spindle"]) == spindles
    assert rows["axes"]["value"] == {"names": axes, "controlled": len(axes)}
    assert rows["spindles"]["value"] == {"names": spindles}
    assert set(rows["timers"]["value"]) == set(TIMER_KINDS)
    assert rows["timers"]["value"]["power_on"]["minutes"] == state.timer(0).minutes
    program = rows["program"]["value"]
    assert program["name"] == state.exec_program().name and program["path"] == state.main_program_path()
    assert [p["number"] for p in rows["programs"]["value"]] == [p.number for p in state.program_directory(1, 19)]
    assert set(rows["speeds"]["value"]) == {"feed", "spindle"}


def test_work_offsets_are_named_per_g_code_and_axis_through_the_packed_surface(
        sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "read", "--json", "--transport", "packed", sim.packed.address, "work_offsets")
    assert code == 0, err
    value = json_lines(out)["work_offsets"]["value"]
    assert list(value) == ["G54", "G55", "G56", "G57", "G58", "G59"]
    assert value["G55"] == dict(zip(sim.state.axis_names(), sim.state.work_offsets(2), strict=True))


def test_modal_and_tool_number_are_named_reads_through_the_packed_surface(
        sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "read", "--json", "--transport", "packed", sim.packed.address, "modal",
                             "tool_number")
    assert code == 0, err
    rows = json_lines(out)
    assert rows["modal"]["value"]["13"] == "G54" and rows["tool_number"]["value"] in range(1, 5)


def test_work_offsets_on_the_native_transport_fail_saying_there_is_no_wire_code(
        sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "read", "--json", sim.address, "work_offsets")
    assert code != 0
    error = json_lines(out)["work_offsets"]["error"]
    assert error["type"] == "NotSupported" and "no public" in error["message"]


def test_named_reads_match_the_target_grammar() -> None:
    assert set(READ_NAMES) == set(NAMED_READS)


def read_with_ew(sim: Sim, capsys: pytest.CaptureFixture[str], ew: dict[str, int],
                 *items: str) -> tuple[int, str, str]:
    """`focas-edge read --json` while the simulator answers these EW codes."""
    sim.native.faults.update({"ew": ew})
    try:
        return run_cli(capsys, "read", "--json", sim.address, *items)
    finally:
        sim.native.faults.clear()


def test_positions_degrade_per_kind(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    """One position kind answered EW_NOOPT (as a real EDM answers distance-to-go): the other kinds are
    printed, the refused one is named on stderr, the item does not fail."""
    code, out, err = read_with_ew(sim, capsys, {"positions/7": 6}, "positions")
    assert code == 3, err
    row = json_lines(out)["positions"]
    assert row["error"] is None and set(row["refused"]) == {"distance"}
    axes = row["value"]
    assert set(axes) == set(sim.state.axis_names())
    assert all(set(kinds) == {"absolute", "machine", "relative"} for kinds in axes.values())
    assert "positions: distance" in err and "EW_NOOPT" in err


# Each composite with parts refused as real controls refuse them: (item, EW faults, refused parts, value keys).
PARTIAL_READS = [
    # a 16i-W EDM: the program number answers, the executing program's name and its path are EW_FUNC
    ("program", {"exec_program_name": 1, "main_program_path": 1}, {"name", "path"}, {"running", "main", "sequence"}),
    # a 31i lathe: servo loads answer, spindle names are EW_FUNC
    ("loads", {"spindle_names": 1}, {"spindle"}, {"servo"}),
    ("loads", {"servo_meter": 6}, {"servo"}, {"spindle"}),
    ("timers", {"read_timer/1": 1, "read_timer/4": 6}, {"operating", "free"}, {"power_on", "cutting", "cycle"}),
    ("speeds", {"actual_feed": 1}, {"feed"}, {"spindle"}),
    ("alarms", {"alarm_messages": 1}, {"active"}, {"status"}),
    ("axes", {"controlled_axes": 1}, {"controlled"}, {"names"}),
    ("tool_offsets", {"tool_offsets/1/3": 6}, {"radius_wear"}, None),
]


@pytest.mark.parametrize(("item", "ew", "refused", "kept"), PARTIAL_READS,
                         ids=[f"{row[0]}-{'+'.join(sorted(row[2]))}" for row in PARTIAL_READS])
def test_composite_read_prints_every_part_answered_and_names_each_refused(
        sim: Sim, capsys: pytest.CaptureFixture[str], item: str, ew: dict[str, int], refused: set[str],
        kept: set[str] | None) -> None:
    """Exit 3 (some parts refused); the value holds every part the CNC answered; `refused` and stderr name each
    refused part with its return code."""
    code, out, err = read_with_ew(sim, capsys, ew, item)
    assert code == 3, err
    row = json_lines(out)[item]
    assert row["error"] is None
    assert set(row["refused"]) == refused
    assert {error["code"] for error in row["refused"].values()} <= {"EW_FUNC", "EW_NOOPT"}
    if kept is not None:
        assert set(row["value"]) == kept
    else:  # tool offsets: every offset number keeps the kinds that answered
        assert row["value"] and all(set(kinds) == set(TOOL_OFFSET_KINDS) - refused for kinds in row["value"].values())
    for part in refused:
        assert f"{item}: {part}: EW_" in err


def test_composite_read_with_every_part_refused_fails_whole(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = read_with_ew(sim, capsys, {"servo_meter": 1, "spindle_load": 1}, "loads", "macro:500")
    assert code == 1, err
    rows = json_lines(out)
    assert rows["loads"]["error"]["code"] == "EW_FUNC" and set(rows["loads"]["refused"]) == {"servo", "spindle"}
    assert rows["macro:500"]["error"] is None


def test_refused_parts_are_rows_of_the_table(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    sim.native.faults.update({"ew": {"exec_program_name": 1}})
    try:
        code, out, _ = run_cli(capsys, "read", sim.address, "program", "macro:500")
    finally:
        sim.native.faults.clear()
    assert code == 3
    assert any(line.split()[:3] == ["name", "REFUSED", "EW_FUNC"] for line in out.splitlines())
    assert any(line.split()[:1] == ["main"] for line in out.splitlines())


def test_all_axes_reads_are_keyed_by_axis_name(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "read", "--json", sim.address, "param:1850/all", "diag:308-309/all")
    assert code == 0, err
    rows = json_lines(out)
    names = sim.state.axis_names()
    assert rows["param:1850/all"]["value"] == {n: sim.state.read_param_value(1850, i + 1)
                                               for i, n in enumerate(names)}
    diags = rows["diag:308-309/all"]["value"]
    assert set(diags) == {"308", "309"} and all(list(v) == names for v in diags.values())


def test_axis_type_number_refused_at_axis_0_is_read_per_axis(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    """A control answering EW_ATTRIB for an axis-type number read with axis 0: read it for every axis."""
    code, out, err = read_with_ew(sim, capsys, {"read_params/1850/0": 4}, "param:1850")
    assert code == 0, err
    value = json_lines(out)["param:1850"]["value"]
    assert list(value) == sim.state.axis_names()


def test_path_option_reads_that_path(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    """The simulated 30i has one path: path 2 is refused with EW_PATH, by the CNC, naming it."""
    code, out, err = run_cli(capsys, "read", "--json", "--path", "2", sim.address, "status")
    assert code == 1
    assert json_lines(out)["status"]["error"]["code"] == "EW_PATH" and "EW_PATH" in err
    code, _, err = run_cli(capsys, "read", "--transport", "packed", "--path", "2", "unix:/tmp/x.sock", "status")
    assert code == 2 and "reads path 1 only" in err


def test_read_table_is_readable(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "read", sim.address, "macro:500-501", "status")
    assert code == 0
    lines = out.splitlines()
    assert lines[0].split()[:2] == ["macro:500-501", "#500"]
    assert lines[1].split()[0] == "#501"
    assert any(line.startswith("status") for line in lines)


def test_failed_item_fails_alone_and_names_the_ew_code(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "read", "--json", sim.address, "macro:500", "macro:99999", "pmc:R100")
    assert code == 1
    rows = json_lines(out)
    assert rows["macro:500"]["error"] is None and rows["pmc:R100"]["error"] is None
    error = rows["macro:99999"]["error"]
    assert error["code"] == "EW_NUMBER" and error["ew"] == 3
    assert "macro:99999" in err and "EW_NUMBER" in err


@pytest.mark.parametrize(
    "argv",
    [("read", "127.0.0.1:1", "macro:abc"), ("read", "unix:/tmp/x.sock", "status"),
     ("write", "127.0.0.1:1", "macro:500"), ("write", "127.0.0.1:1", "macro:500=abc"),
     ("write", "127.0.0.1:1", "pmc:R100=256"), ("write", "127.0.0.1:1", "diag:980=1"),
     ("write", "127.0.0.1:1", "pmc:R100-R101=1"), ("read", "127.0.0.1:1")],
)
def test_bad_usage_exits_2_without_connecting(argv: tuple[str, ...], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        raise SystemExit(main(list(argv)))
    assert info.value.code == 2
    assert capsys.readouterr().err


def test_unreachable_cnc_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    code, out, err = run_cli(capsys, "read", "--json", "--timeout", "2", f"127.0.0.1:{port}", "status", "clock")
    assert code == 1
    rows = json_lines(out)
    assert all(row["error"] is not None for row in rows.values())
    assert "status" in err


def test_write_macro_pmc_bit_and_typed(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    sim.state.write_pmc("R", 120, bytes([0b0000_0001]), protocol="admin")
    code, out, err = run_cli(capsys, "write", sim.address, "macro:510=1.25", "macro:511=-0.001",
                             "pmc:R121=0x41", "pmc:R120.3=1", "pmc:D2300.word=600", "pmc:R122-R123=7,8")
    assert code == 0, err
    assert sim.state.read_macro(510) == 1.25 and sim.state.read_macro(511) == -0.001
    assert sim.state.read_pmc_bytes("R", 120, 123) == bytes([0b0000_1001, 0x41, 7, 8])
    assert sim.state.read_pmc("D", 2300, 2301, 1) == [600]
    assert "pmc:R120.3=1  ok, reads back 1" in out
    targets = [w.target for w in sim.state.writes() if w.protocol == "native"]
    assert "macro:510" in targets and "pmc:R121" in targets


def test_write_pmc_range_over_32_bytes_is_chunked(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    values = list(range(1, 41))
    code, _, err = run_cli(capsys, "write", sim.address, f"pmc:R150-R189={','.join(map(str, values))}")
    assert code == 0, err
    assert list(sim.state.read_pmc_bytes("R", 150, 189)) == values


def test_write_stops_at_first_failure(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    before = len(sim.state.writes())
    code, out, err = run_cli(capsys, "write", "--json", sim.address, "macro:99999=1", "macro:512=5")
    assert code == 1
    rows = json_lines(out)
    assert list(rows) == ["macro:99999=1"] and rows["macro:99999=1"]["error"]["code"] == "EW_NUMBER"
    assert "EW_NUMBER" in err
    assert len(sim.state.writes()) == before


def test_parameter_write_needs_the_write_switch(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    packed = sim.packed.address
    sim.state.set_param_write_enable(False)
    code, out, err = run_cli(capsys, "write", "--json", "--transport", "packed", packed, "param:6711=5")
    assert code == 1
    assert json_lines(out)["param:6711=5"]["error"]["code"] == "EW_PASSWD"
    sim.state.set_param_write_enable(True)
    try:
        code, out, err = run_cli(capsys, "write", "--transport", "packed", packed, "param:6711=5")
        assert code == 0, err
        assert sim.state.read_param_value(6711) == 5
    finally:
        sim.state.set_param_write_enable(False)


def test_native_parameter_write_is_not_supported(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_cli(capsys, "write", sim.address, "param:6711=0")
    assert code == 1
    assert "param:6711=0" in err and "not supported" in err


def test_packed_transport_reads_too(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "read", "--json", "--transport", "packed", sim.packed.address,
                             "macro:500", "pmc:R100.3", "param:1815/1")
    assert code == 0, err
    rows = json_lines(out)
    assert rows["macro:500"]["value"] == sim.state.read_macro(500)
    assert rows["pmc:R100.3"]["value"] in (0, 1)


def test_console_entry_point_as_a_subprocess(sim: Sim) -> None:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, "-m", "edge", "read", "--json", sim.address, "macro:500"],
                          capture_output=True, text=True, timeout=60, env=env, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["value"] == sim.state.read_macro(500)


def test_write_whose_read_back_differs_exits_1(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    # The CNC owns F (CNC-to-PMC signals): it overwrites F0 at once, so the write does not hold.
    code, out, err = run_cli(capsys, "write", "--force", sim.address, "pmc:F0=1")
    assert code == 1
    assert "pmc:F0=1" in err and "reads back" in err and "not 1" in err
    assert "ok" not in out


def test_write_whose_read_back_differs_exits_1_in_json_too(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "write", "--json", "--force", sim.address, "pmc:F0=1", "macro:513=1")
    assert code == 1
    rows = json_lines(out)
    assert list(rows) == ["pmc:F0=1"] and rows["pmc:F0=1"]["error"]["code"] == "read_back_differs"
    assert sim.state.read_macro(513) != 1  # stopped at the first failure


@pytest.mark.parametrize("assignment", ["pmc:X0=1", "pmc:F1.2=1", "pmc:X10-X11=0,0", "pmc:f0=1"])
def test_writing_machine_inputs_or_cnc_signals_needs_force(sim: Sim, capsys: pytest.CaptureFixture[str],
                                                           assignment: str) -> None:
    before = len(sim.state.writes())
    with pytest.raises(SystemExit) as info:
        raise SystemExit(main(["write", sim.address, assignment]))
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--force" in err and ("machine inputs" in err or "CNC-to-PMC" in err)
    assert len(sim.state.writes()) == before


def test_write_that_holds_exits_0(sim: Sim, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "write", sim.address, "pmc:R130=-1", "pmc:D2310.word=65535", "macro:514=0.5")
    assert code == 0, err
    assert "pmc:R130=-1  ok, reads back 255" in out


def test_parameter_value_outside_its_type_is_refused_before_writing(sim: Sim,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    sim.state.set_param_write_enable(True)
    try:
        before = len(sim.state.writes("param:"))
        code, _, err = run_cli(capsys, "write", "--transport", "packed", sim.packed.address, "param:6711=2147483648")
        assert code == 1
        assert "two-word" in err and "2147483648" in err and "wrong_type" in err
        assert len(sim.state.writes("param:")) == before  # nothing reached the CNC (it would land as -2^31)
    finally:
        sim.state.set_param_write_enable(False)
