"""check-config shows every problem of a file at once, each with the line it is on."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from edge import ConfigError
from edge.cli import main
from edge.config import parse_config


def problems_of(text: str, environ: dict[str, str] | None = None) -> list[str]:
    with pytest.raises(ConfigError) as info:
        parse_config(textwrap.dedent(text).lstrip("\n"), "test.yaml", environ or {})
    return info.value.problems


def test_a_missing_ca_file_does_not_hide_the_login_problems(tmp_path: Path) -> None:
    problems = problems_of(f"""
        mqtt:
          host: broker
          tls: {{ca_file: {tmp_path / 'no-ca.pem'}}}
          password_file: {tmp_path / 'no-password'}
          sparkplug: {{group_id: g, edge_node_id: n}}
        machines:
          - {{id: m1, host: 10.0.0.1}}
        """)
    assert len(problems) == 3, problems
    assert problems[0].startswith("mqtt.tls.ca_file: no such file")
    assert any(p.startswith("mqtt.username: a password needs a username") for p in problems)
    assert any(p.startswith("mqtt.password_file: cannot read") for p in problems)


def test_an_unset_password_variable_shows_beside_schema_errors() -> None:
    problems = problems_of("""
        mqtt:
          host: broker
          username: u
          password_env: NOT_SET_HERE
          sparkplug: {group_id: g, edge_node_id: n}
        machines:
          - {id: m1}
        """)
    assert [p.split(":")[0] for p in problems] == ["machines[0].host", "mqtt.password_env"]


def test_schema_errors_carry_the_line_of_the_offending_key() -> None:
    problems = problems_of("""
        mqtt:
          host: broker
          sparkplug: {group_id: g, edge_node_id: n}
          keepalive: 1
        machines:
          - id: m1
            host: 10.0.0.1
          - id: m2
            host: 10.0.0.2
            poll:
              pmc:
                - {range: D100-D103, data_type: word}
                - {range: R9-R3}
              perods: {status: 1s}
          - id: m3
        """)
    assert "mqtt.keepalive: Input should be greater than or equal to 5 (line 4)" in problems
    assert any(p.startswith("machines[1].poll.pmc[1].range: ") and p.endswith("(line 13)") for p in problems)
    assert any(p.startswith("machines[1].poll.perods: unknown key") and p.endswith("(line 14)") for p in problems)
    # a missing key has no line of its own: the entry that lacks it
    assert "machines[2].host: required (line 15)" in problems


def test_check_config_prints_each_problem_with_its_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "edge.yaml"
    config.write_text("mqtt:\n  host: b\n  formats: [json]\nmachines:\n  - id: m1\n    port: 0\n")
    assert main(["check-config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "2 problem(s)" in err
    assert "machines[0].host: required (line 5)" in err
    assert "machines[0].port: Input should be greater than or equal to 1 (line 6)" in err
