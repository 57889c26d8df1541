"""One fleet file for many gateways: each machine names its gateway, a gateway loads only its own machines,
gets its own edge node id and overrides, and every mistake in the split is named with its line."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from edge import ConfigError
from edge.cli import main
from edge.config import parse_config
from tests.unit.config.minimal import MINIMAL, problems_of

FLEET = """
mqtt:
  host: broker
  sparkplug: {group_id: plant}
gateways:
  hall-a: {}
  hall-b:
    mqtt: {host: broker-b, port: 1884}
    state_dir: /var/lib/focas-edge-b
machines:
  - {id: lathe-1, host: 10.0.1.1, gateway: hall-a}
  - {id: mill-2, host: 10.0.2.2, gateway: hall-b, paths: 2}
  - {id: lathe-3, host: 10.0.1.3, gateway: hall-a}
"""


def fleet(gateway: str | None, text: str = FLEET, environ: dict[str, str] | None = None) -> object:
    return parse_config(textwrap.dedent(text), "fleet.yaml", environ or {}, gateway=gateway)


def problems(text: str, gateway: str | None = None) -> list[str]:
    with pytest.raises(ConfigError) as info:
        fleet(gateway, text)
    return info.value.problems


def test_a_gateway_loads_only_the_machines_that_name_it_with_its_own_overrides() -> None:
    a = parse_config(textwrap.dedent(FLEET), "fleet.yaml", {}, gateway="hall-a")
    b = parse_config(textwrap.dedent(FLEET), "fleet.yaml", {}, gateway="hall-b")
    assert [m.id for m in a.machines] == ["lathe-1", "lathe-3"]
    assert [d.id for d in b.devices()] == ["mill-2", "mill-2-path2"]  # a machine's paths go with it
    assert (a.mqtt.host, a.mqtt.port, b.mqtt.host, b.mqtt.port) == ("broker", None, "broker-b", 1884)
    assert b.resolved_state_dir == Path("/var/lib/focas-edge-b")
    assert (a.gateway, b.gateway) == ("hall-a", "hall-b")
    assert a.fleet == b.fleet == {"hall-a": ["lathe-1", "lathe-3"], "hall-b": ["mill-2"]}


def test_each_gateway_is_its_own_edge_node_named_after_it_unless_its_entry_says() -> None:
    text = FLEET.replace("  hall-a: {}", "  hall-a: {mqtt: {sparkplug: {edge_node_id: gw-hall-a}}}")
    a = parse_config(textwrap.dedent(text), "fleet.yaml", {}, gateway="hall-a")
    b = parse_config(textwrap.dedent(text), "fleet.yaml", {}, gateway="hall-b")
    assert a.mqtt.sparkplug is not None and b.mqtt.sparkplug is not None
    assert (a.mqtt.sparkplug.edge_node_id, b.mqtt.sparkplug.edge_node_id) == ("gw-hall-a", "hall-b")
    assert a.mqtt.sparkplug.group_id == b.mqtt.sparkplug.group_id == "plant"


def test_a_shared_edge_node_id_or_client_id_is_refused() -> None:
    shared = FLEET.replace("sparkplug: {group_id: plant}", "sparkplug: {group_id: plant, edge_node_id: gw}")
    found = problems(shared, "hall-a")
    assert any(p.startswith("gateways.hall-b: Sparkplug edge node id 'gw' is also gateway 'hall-a''s")
               for p in found), found
    client = FLEET.replace("  host: broker\n", "  host: broker\n  client_id: edge\n", 1)
    assert any("MQTT client id 'edge' is also gateway 'hall-a''s" in p for p in problems(client)), problems(client)
    prefix = FLEET.replace("  host: broker\n", "  host: broker\n  json: {prefix: plant/focas}\n", 1)
    assert any("JSON prefix 'plant/focas' is also gateway 'hall-a''s" in p for p in problems(prefix)), problems(prefix)
    own = prefix.replace("mqtt: {host: broker-b, port: 1884}", "mqtt: {host: broker-b, json: {prefix: plant/b}}")
    assert fleet("hall-b", own) is not None


def test_a_machine_without_a_gateway_or_with_an_unknown_one_is_named_with_its_line() -> None:
    text = FLEET.replace("gateway: hall-b, paths: 2", "gateway: hall-c").replace(
        "  - {id: lathe-3, host: 10.0.1.3, gateway: hall-a}", "  - {id: lathe-3, host: 10.0.1.3}")
    found = problems(text, "hall-a")
    assert "machines[1].gateway: unknown gateway 'hall-c' (defined in gateways: hall-a, hall-b) (line 12)" in found
    assert ("machines[2].gateway: required: the file lists gateways (hall-a, hall-b), so machines[2] (lathe-3) "
            "must name the one that polls it (line 13)") in found


def test_an_unknown_gateway_asked_for_is_refused_with_the_line_of_the_list() -> None:
    assert problems(FLEET, "hall-z") == [
        "gateway 'hall-z' (--gateway or FOCAS_EDGE_GATEWAY) is not in gateways: hall-a, hall-b (line 5)"]


def test_a_gateway_entry_overrides_only_per_box_sections_and_its_bad_values_point_at_it() -> None:
    text = FLEET.replace("mqtt: {host: broker-b, port: 1884}", "mqtt: {host: broker-b, port: 99999}").replace(
        "  hall-a: {}", "  hall-a: {machines: []}")
    found = problems(text)
    assert any(p.startswith("gateways.hall-a.machines: not a section a gateway may override") and p.endswith(
        "(line 6)") for p in found), found
    assert any(p.startswith("gateways.hall-b.mqtt.port: ") and p.endswith("(line 8)") for p in found), found


def test_a_file_without_gateways_refuses_a_gateway_name_anywhere() -> None:
    with_key = MINIMAL.replace("host: 10.0.0.1", "host: 10.0.0.1\n    gateway: hall-a")
    assert problems_of(with_key) == ["machines[0].gateway: names gateway 'hall-a' but the file has no gateways: "
                                     "section listing the gateways (line 8)"]
    with pytest.raises(ConfigError) as info:
        parse_config(MINIMAL, "test.yaml", {}, gateway="hall-a")
    assert "but the file has no gateways: section" in info.value.problems[0]


def test_a_gateway_whose_machines_all_moved_away_runs_empty_with_a_warning() -> None:
    text = FLEET.replace("gateway: hall-b, paths: 2", "gateway: hall-a")
    b = parse_config(textwrap.dedent(text), "fleet.yaml", {}, gateway="hall-b")
    assert b.machines == [] and b.poll_grid_step_s > 0
    assert "gateway 'hall-b' polls no machine: no machine in the file names it" in b.warnings


def test_only_the_chosen_gateways_secret_is_read() -> None:
    text = FLEET.replace("mqtt: {host: broker-b, port: 1884}",
                         "mqtt: {host: broker-b, port: 1884, username: b, password_env: HALL_B_PW}")
    assert fleet("hall-a", text) is not None  # hall-b's secret lives on hall-b's box
    assert any("HALL_B_PW is not set" in p for p in problems(text, "hall-b"))
    assert fleet("hall-b", text, {"HALL_B_PW": "x"}) is not None


def test_check_config_shows_what_this_gateway_polls_and_what_it_leaves(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(textwrap.dedent(FLEET).replace("hall-a: {}", f"hall-a: {{state_dir: {tmp_path / 'a'}}}"))
    assert main(["check-config", str(path), "--gateway", "hall-a"]) == 0
    out = capsys.readouterr().out
    assert "gateway    hall-a (of hall-a, hall-b): polls 2 machine(s), leaves 1 to the others" in out
    assert "left to hall-b     mill-2" in out
    assert "spBv1.0/plant/+/hall-a" in out
    assert "lathe-1" in out and "    mill-2 " not in out
    assert main(["check-config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "gateway hall-a       2 machine(s): lathe-1, lathe-3" in out
    assert "gateway hall-b       1 machine(s): mill-2" in out
    monkeypatch.setenv("FOCAS_EDGE_GATEWAY", "hall-x")
    assert main(["check-config", str(path)]) == 2
    assert "gateway 'hall-x' (--gateway or FOCAS_EDGE_GATEWAY) is not in gateways" in capsys.readouterr().err


def test_run_refuses_a_fleet_file_without_being_told_which_gateway_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("FOCAS_EDGE_GATEWAY", raising=False)
    path = tmp_path / "fleet.yaml"
    path.write_text(textwrap.dedent(FLEET))
    assert main(["run", "--config", str(path)]) == 2
    assert ("the file lists gateways (hall-a, hall-b): say which one this is with --gateway NAME or "
            "FOCAS_EDGE_GATEWAY=NAME") in capsys.readouterr().err

