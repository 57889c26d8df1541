"""`focas-edge probe` against the simulated CNC over TCP: series, record forms, injected EW codes, exit codes."""

from __future__ import annotations

import dataclasses
import json

import pytest

from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, main
from edge.focas import items as it
from edge.focas.client import FocasClient
from edge.focas.packed.client import PackedClient
from edge.focas.probe import Outcome, ProbeReport, ProbeStep, probe, probe_items
from edge.sim.fleet import Fleet, FleetThread, MachineSpec
from tests.helpers import free_port

pytestmark = pytest.mark.integration


def by_name(report: ProbeReport) -> dict[tuple[str, str], ProbeStep]:
    return {(s.function, s.arguments): s for s in report.steps}


def test_every_read_item_class_is_probed() -> None:
    probed = {type(item) for item in probe_items()}
    every = {cls for cls in vars(it).values()
             if isinstance(cls, type) and issubclass(cls, it.ReadItem) and cls is not it.ReadItem}
    assert every - probed == set()


async def test_30i_answers_the_8_byte_record_form_and_refuses_the_4_byte_one() -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        report = await probe(FocasClient("127.0.0.1", fleet[0].port, timeout=2), "sim-30i")
        assert fleet[0].sessions == 0, "the probe closes its session"
    assert report.complete and report.model == "30i-BM"
    steps = by_name(report)
    wide = steps[("ReadParams", "6711 axis 0")]
    assert (wide.command, wide.outcome) == ("0x8d", Outcome.OK)
    narrow = steps[("ReadParams (4-byte form)", "6711 axis 0")]
    assert (narrow.command, narrow.outcome, narrow.ew_name) == ("0x0e", Outcome.NOT_AVAILABLE, "EW_FUNC")
    assert steps[("ReadDiag (4-byte form)", "980 axis 1")].ew_name == "EW_FUNC"
    assert steps[("ReadDiag", "980 axis 1")].works
    tool = steps[("ReadToolOffsets", "radius_wear 1..1")]
    assert (tool.command, tool.works) == ("0x08", True)
    assert steps[("ReadOperatorMessages", "")].command == "0x34" and steps[("ReadOperatorMessages", "")].works
    history = steps[("ReadAlarmHistory", "up to 10")]
    assert history.outcome == Outcome.NOT_SUPPORTED and history.rtt_ms is None  # nothing sent
    for step in report.steps:
        if step.outcome != Outcome.NOT_SUPPORTED:
            assert step.rtt_ms is not None and 0 < step.rtt_ms < 2000, step
    writes = {w.operation: w for w in report.writes}
    assert writes["write_macro"].available and writes["write_pmc"].available
    assert not writes["write_param"].available and not writes["write_param"].transport_has_it


async def test_16i_answers_the_4_byte_form_and_refuses_the_8_byte_one() -> None:
    async with Fleet([MachineSpec(profile="16i")], base_port=0) as fleet:
        report = await probe(FocasClient("127.0.0.1", fleet[0].port, timeout=2), "sim-16i")
    steps = by_name(report)
    assert report.model == "16i-BM"
    assert (steps[("ReadParams", "6711 axis 0")].command, steps[("ReadParams", "6711 axis 0")].works) == \
        ("0x0e", True)
    refused = steps[("ReadParams (8-byte form)", "6711 axis 0")]
    assert (refused.command, refused.ew_name) == ("0x8d", "EW_FUNC")
    assert steps[("ReadDiag (8-byte form)", "980 axis 1")].ew_name == "EW_FUNC"


async def test_injected_ew_codes_are_reported_per_function_and_the_rest_still_work() -> None:
    spec = MachineSpec(profile="30i", faults={"ew": {"read_macros": 6, "servo_meter": 5}})
    async with Fleet([spec], base_port=0) as fleet:
        report = await probe(FocasClient("127.0.0.1", fleet[0].port, timeout=2), "sim")
    steps = by_name(report)
    macros = steps[("ReadMacros", "#500..#505")]
    assert (macros.outcome, macros.ew_code, macros.ew_name) == (Outcome.NOT_AVAILABLE, 6, "EW_NOOPT")
    servo = steps[("ReadServoMeter", "")]
    assert (servo.outcome, servo.ew_name) == (Outcome.CNC_ERROR, "EW_DATA")
    assert steps[("ReadStatus", "")].works and steps[("ReadPmc", "F0..F3 byte")].works
    writes = {w.operation: w for w in report.writes}
    assert not writes["write_macro"].available and writes["write_macro"].transport_has_it


async def test_packed_transport_probe_has_no_record_form_rows() -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0, packed_base_port=0) as fleet:
        port = fleet[0].packed_port
        report = await probe(PackedClient(f"tcp:127.0.0.1:{port}", timeout=2), f"127.0.0.1:{port}")
    steps = by_name(report)
    assert report.complete and report.transport == "packed"
    assert steps[("ReadAlarmHistory", "up to 10")].works
    assert not any("form" in s.function for s in report.steps)
    assert {w.operation: w.available for w in report.writes}["write_param"]


def test_cli_json_and_exit_codes(capsys: pytest.CaptureFixture[str]) -> None:
    with FleetThread(Fleet([MachineSpec(profile="16i", faults={"ew": {"read_pmc": 1}})], base_port=0)) as fleet:
        code = main(["probe", f"127.0.0.1:{fleet[0].port}", "--json", "--timeout", "2"])
    out = capsys.readouterr().out
    assert code == EXIT_OK
    doc = json.loads(out)
    assert doc["complete"] and doc["cnc"]["model"] == "16i-BM" and doc["cnc"]["record_form"].startswith("4-byte")
    pmc = next(f for f in doc["functions"] if f["function"] == "ReadPmc")
    assert (pmc["outcome"], pmc["ew_name"], pmc["ew_code"]) == ("not-available", "EW_FUNC", 1)
    assert all(w["tried"] is False for w in doc["writes"])

    assert main(["probe", f"127.0.0.1:{free_port()}", "--timeout", "1"]) == EXIT_FAILURE
    assert "PROBE INCOMPLETE" in capsys.readouterr().out
    assert main(["probe", "127.0.0.1:99999"]) == EXIT_USAGE
    assert main(["probe", "unix:/tmp/x.sock"]) == EXIT_USAGE  # the native transport is TCP only


def test_cli_table_names_the_refused_form(capsys: pytest.CaptureFixture[str]) -> None:
    with FleetThread(Fleet([MachineSpec(profile="30i")], base_port=0)) as fleet:
        assert main(["probe", f"127.0.0.1:{fleet[0].port}"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "model 30i-BM" in out
    refused = [line for line in out.splitlines() if "ReadParams (4-byte form)" in line]
    assert refused and all("0x0e" in line and "EW_FUNC (1)" in line for line in refused)
    assert "writes (checked, never sent)" in out


def test_probe_step_is_plain_data() -> None:
    step = ProbeStep("ReadStatus", "", Outcome.OK, 1.0)
    assert dataclasses.replace(step, outcome=Outcome.FAILED).works is False
