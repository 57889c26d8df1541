"""Scenario files: a fleet from YAML, and every problem of a bad one listed."""

from __future__ import annotations

from pathlib import Path

import pytest

from edge import ConfigError
from edge.sim.fleet import Fleet
from edge.sim.scenario import load_scenario, parse_scenario


def test_scenario_file(tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(
        "base_port: 0\nadmin_port: 0\nmachines:\n"
        "  - {name: mill, profile: 30i, timezone: Europe/Berlin, clock_offset: 12.5,"
        " cycle: {cut_seconds: 3, idle_seconds: 2, alarm_every: 1}, macros: {500: 2.5},"
        " faults: {latency: 0.1}}\n"
        "  - {name: lathe, profile: 16i, count: 2}\n")
    scenario = load_scenario(path)
    assert [m.name for m in scenario.machines] == ["mill", "lathe-1", "lathe-2"]
    mill = scenario.machines[0]
    assert (mill.timezone, mill.clock_offset, mill.cycle.alarm_every, mill.macros) == (
        "Europe/Berlin", 12.5, 1, {500: 2.5})
    fleet = Fleet(scenario.machines, base_port=0)
    assert fleet[0].state.read_macro(500) == 2.5 and fleet[0].faults.latency == 0.1
    assert fleet[1].state.profile.name == "16i"


def test_bad_scenario_lists_every_problem() -> None:
    with pytest.raises(ConfigError) as caught:
        parse_scenario({"machines": [{"profile": "18i", "timezone": "Mars/Base", "faults": {"boom": 1}},
                                     {"cycle": {"cut_seconds": -1}}], "base_port": 70000})
    text = "\n".join(caught.value.problems)
    for fragment in ("machines.0.profile", "machines.0.timezone", "machines.0.faults",
                     "machines.1.cycle.cut_seconds", "base_port"):
        assert fragment in text
    with pytest.raises(ConfigError):
        parse_scenario({"machines": []})
