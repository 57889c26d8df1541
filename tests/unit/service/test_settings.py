"""The config turned into collect's and command's settings: values carried over, nothing decided on the way."""

from __future__ import annotations

import ast
from pathlib import Path
from zoneinfo import ZoneInfo

import edge
from edge.collect.tickgrid import DEFAULT_STEP_S
from edge.command.settings import AllowRule, RateLimit, WritePolicy
from edge.config import SHORTEST_PERIOD_S, parse_config
from edge.focas.model import PmcType
from edge.focas.targets import PmcTarget
from edge.service.settings import command_settings, machine_settings

CONFIG = """
mqtt: {host: b, formats: [json]}
state_dir: /tmp/state
alarms: {mode: ActivePlusHistory, history_interval: 5m, history_depth: 50}
writes: {enabled: true, allow: [{target: "macro:500-599", max: 10}], max_payload_bytes: 2048}
machines:
  - id: lathe
    host: h
    timezone: Europe/Berlin
    series: 0i-TF
    paths: 2
    poll:
      periods: {status: 250ms, pmc: 2s}
      macros: [{first: 600, name: Tool/Offset, deadband: 0.1}]
      pmc: [{range: D2204-D2207, data_type: word}]
      params: [{number: 1850, axis: all}]
    writes: {allow: [{target: "pmc:R100-R199"}], rate_limit: {max_writes: 2, per_s: 1}}
  - {id: mill, host: h2, port: 8194, alarms: {mode: ActiveOnly}, writes: {enabled: false}}
"""


def test_a_path_device_knows_its_control_and_carries_the_machine_values() -> None:
    config = parse_config(CONFIG, "t", {})
    path2 = machine_settings(config, config.machine("lathe-path2"))
    assert (path2.id, path2.path, path2.path_devices, path2.paths) == ("lathe-path2", 2, ("lathe", "lathe-path2"), 2)
    assert (path2.endpoint, path2.zone, path2.series) == ("h:8193", ZoneInfo("Europe/Berlin"), "0i-TF")
    poll = path2.poll
    assert (poll.periods.status, poll.periods.pmc, poll.periods.alarm_history) == (0.25, 2.0, 300.0)
    assert [(m.first, m.last, m.names, m.deadband) for m in poll.macros] == [(600, 600, ("Tool/Offset",), 0.1)]
    assert [(p.target, p.names) for p in poll.pmc] == [
        (PmcTarget("D", 2204, 2207, PmcType.WORD), ("PMC/D2204", "PMC/D2206"))]
    assert [(p.number, p.axis, p.name) for p in poll.params] == [(1850, -1, "Param/1850")]
    assert (poll.alarm_history, poll.alarm_history_depth) == (True, 50)
    mill = machine_settings(config, config.machine("mill"))
    assert (mill.path_devices, mill.endpoint, mill.poll.alarm_history) == (("mill",), "h2:8194", False)


def test_each_device_gets_the_merged_write_policy_of_its_machine() -> None:
    config = parse_config(CONFIG, "t", {})
    settings = command_settings(config)
    assert (settings.state_dir, settings.max_payload_bytes) == (Path("/tmp/state"), 2048)
    assert list(settings.machines) == list(settings.policies) == ["lathe", "lathe-path2", "mill"]
    assert settings.policies["lathe-path2"] == WritePolicy(
        enabled=True, allow=(AllowRule("macro:500-599", None, 10.0), AllowRule("pmc:R100-R199")),
        rate_limit=RateLimit(2, 1.0), reconnect_deadline_s=10.0)
    assert settings.policies["mill"].enabled is False
    assert settings.machines["lathe-path2"] == machine_settings(config, config.machine("lathe-path2"))


def test_the_default_tick_grid_fits_the_shortest_period_the_config_accepts() -> None:
    assert DEFAULT_STEP_S == SHORTEST_PERIOD_S / 2


def test_collect_and_command_never_import_the_config() -> None:
    """They take settings; only edge.service.settings reads the pydantic config models for them."""
    root = Path(edge.__file__).parent
    offenders = []
    for package in ("collect", "command"):
        for module in sorted((root / package).glob("*.py")):
            for node in ast.walk(ast.parse(module.read_text())):
                names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                         else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
                offenders += [f"{package}/{module.name}: {name}" for name in names
                              if name == "edge.config" or name.startswith("edge.config.")]
    assert offenders == []
