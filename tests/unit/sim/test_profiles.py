"""The control profiles: what each series says about itself."""

from __future__ import annotations

import pytest

from edge.sim.profiles import PROFILES, get_profile


def test_profiles() -> None:
    assert set(PROFILES) >= {"0i-F", "16i", "30i", "31i"}
    assert get_profile("16i").sysinfo.max_axis == 8 and get_profile("31i").sysinfo.max_axis == 32
    assert get_profile("16I") is PROFILES["16i"] and get_profile("31i-B") is PROFILES["31i"]
    assert {p.response_version for p in PROFILES.values()} == {2, 3, 4}
    with pytest.raises(ValueError, match="expected one of"):
        get_profile("18i")


def test_sim_help_lists_every_profile_on_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from edge.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["sim", "--help"])
    assert exit_info.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    for name, profile in PROFILES.items():
        mine = [line for line in lines if line.split()[:1] == [name]]
        assert len(mine) == 1, f"{name}: {mine}"
        assert profile.summary and profile.summary in mine[0]


def test_each_path_of_a_two_path_lathe_reports_its_own_program_path() -> None:
    from edge.sim.state import MachineState

    lathe = MachineState("31i-2p", name="lathe")
    second = lathe.for_path(2)
    assert second is not None
    assert lathe.main_program_path().startswith("//CNC_MEM/USER/PATH1/")
    assert second.main_program_path() == f"//CNC_MEM/USER/PATH2/O{second.program_numbers().main:04d}"
