"""Loading a file: every problem with its path and line, YAML errors, shipped examples, check-config."""

from __future__ import annotations

import contextlib
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from edge import ConfigError
from edge.cli import main
from edge.config import format_path, load_config, parse_config
from tests.unit.config.minimal import MINIMAL, problems_of

REPO = Path(__file__).resolve().parents[3]


def test_every_problem_is_listed_with_its_path() -> None:
    problems = problems_of("""
        mqtt:
          host: broker
          sparkplug: {group_id: "a+b", edge_node_id: n}
          colour: blue
        machines:
          - id: m1
            host: h
          - id: m2
            host: h
          - id: m3
            host: h
            timezone: Mars/Olympus
            poll:
              pmc:
                - {range: R103-R100}
              macros: ["600-599"]
    """)
    assert "machines[2].poll.pmc[0].range: end 100 before start 103 (line 16)" in problems
    assert "machines[2].poll.macros[0].last: end 599 before start 600 (line 17)" in problems
    assert any(p.startswith("machines[2].timezone: unknown IANA time zone 'Mars/Olympus'") for p in problems)
    assert any(p.startswith("mqtt.sparkplug.group_id: 'a+b' contains +") for p in problems)
    assert any(p.startswith("mqtt.colour: unknown key (expected one of: ") for p in problems)
    assert len(problems) == 5


def test_yaml_syntax_error_names_the_line() -> None:
    problems = problems_of("mqtt:\n  host: [broker\nmachines: []\n")
    assert len(problems) == 1
    assert problems[0].startswith("line 3, column")
    assert "YAML syntax" in problems[0]


def test_duplicate_yaml_key_is_an_error() -> None:
    problems = problems_of("mqtt: {host: a}\nmqtt: {host: b}\nmachines: []\n")
    assert "given twice" in problems[0] and "line 2" in problems[0]


@pytest.mark.parametrize("text", ["", "# nothing\n", "- a\n- b\n"])
def test_empty_or_non_mapping_file(text: str) -> None:
    assert len(problems_of(text)) == 1


def test_duplicate_machine_ids_ignoring_case_even_beside_other_errors() -> None:
    problems = problems_of("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: Mill, host: h}
          - {id: mill, host: h, timezone: Nowhere/Land}
    """)
    assert any(p.startswith("machines[1].id: 'mill' is already the id of machines[0]") for p in problems)
    assert any(p.startswith("machines[1].timezone") for p in problems)


def test_format_path() -> None:
    assert format_path(["machines", 2, "poll", "pmc", 0, "range"]) == "machines[2].poll.pmc[0].range"
    assert format_path([]) == "(top level)"


@pytest.mark.parametrize("name", ["edge.yaml", "single-machine.yaml"])
def test_shipped_examples_are_valid(name: str) -> None:
    config = load_config(REPO / "config" / name, environ={})
    assert config.machines


def test_tls_example_only_lacks_its_certificate_files() -> None:
    with pytest.raises(ConfigError) as info:
        load_config(REPO / "config" / "tls-broker.yaml", environ={})
    problems = info.value.problems
    assert [p.split(":")[0] for p in problems] == ["mqtt.tls.ca_file", "mqtt.tls.cert_file", "mqtt.tls.key_file",
                                                   "mqtt.password_file"]
    assert all("no such file" in p or "No such file" in p for p in problems)


def test_unreadable_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(tmp_path / "missing.yaml")
    assert "cannot read the file" in info.value.problems[0]


def test_check_config_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.yaml"
    good.write_text(MINIMAL + "alarms: {history_depth: 999}\n")
    assert main(["check-config", str(good)]) == 0
    out, err = capsys.readouterr()
    assert "valid" in out and "m1" in out
    assert "warning: alarms.history_depth: 999" in err
    two_paths = tmp_path / "two-paths.yaml"
    two_paths.write_text(MINIMAL + "    paths: 2\n")
    assert main(["check-config", str(two_paths)]) == 0
    assert "2 paths (devices m1, m1-path2)" in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text(MINIMAL.replace("host: 10.0.0.1", "host: 10.0.0.1\n    port: 0\n    timezone: X/Y"))
    assert main(["check-config", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert "2 problem(s)" in err and "machines[0].port" in err and "machines[0].timezone" in err


_yaml_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10, 70000) | st.floats(allow_nan=False) | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=20,
)


_keys = st.sampled_from(["mqtt", "machines", "alarms", "writes", "state_dir", "http", "spool", "poll", "id",
                         "host", "pmc", "range", "macros", "sparkplug", "formats", "x"])


@given(st.dictionaries(_keys, _yaml_values, max_size=6))
def test_arbitrary_documents_only_raise_config_error(document: dict[str, object]) -> None:
    text = yaml.safe_dump(document)
    try:
        parse_config(text, "fuzz.yaml", {})
    except ConfigError as exc:
        assert exc.problems and all(isinstance(p, str) and ": " in p for p in exc.problems)


@given(st.text(max_size=200))
def test_arbitrary_text_only_raises_config_error(text: str) -> None:
    with contextlib.suppress(ConfigError):
        parse_config(text, "fuzz.yaml", {})
