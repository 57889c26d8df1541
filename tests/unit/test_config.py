from __future__ import annotations

import contextlib
import textwrap
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from edge import ConfigError
from edge.cli import main
from edge.collect.poller import default_session
from edge.config import (
    DEFAULT_STATE_DIR,
    Config,
    format_path,
    load_config,
    parse_config,
)
from edge.focas.client import MAX_SUBPACKETS
from edge.focas.model import PmcType
from edge.service.settings import machine_settings

REPO = Path(__file__).resolve().parents[2]

MINIMAL = """
mqtt:
  host: broker
  sparkplug: {group_id: g, edge_node_id: n}
machines:
  - id: m1
    host: 10.0.0.1
"""


def problems_of(text: str, environ: dict[str, str] | None = None) -> list[str]:
    with pytest.raises(ConfigError) as info:
        parse_config(textwrap.dedent(text), "test.yaml", environ or {})
    return info.value.problems


def parse(text: str, environ: dict[str, str] | None = None) -> Config:
    return parse_config(textwrap.dedent(text), "test.yaml", environ or {})


def test_minimal_config_gets_the_documented_defaults() -> None:
    config = parse(MINIMAL)
    machine = config.machines[0]
    assert machine.port == 8193 and machine.transport == "focas" and machine.timezone == "UTC"
    assert machine.endpoint == "10.0.0.1:8193"
    assert machine.poll.periods.status == 0.25
    assert machine.poll.periods.macros == 1.0 and machine.poll.periods.pmc == 1.0
    assert machine.poll.periods.params == 60.0
    assert machine.max_skew_s == 60.0
    assert config.alarms.mode == "ActiveOnly"
    assert config.alarms.history_interval == 300.0 and config.alarms.history_depth == 100
    assert config.writes.enabled is False
    assert config.http.enabled is False and config.http.host == "127.0.0.1"
    assert config.mqtt.protocol == "3.1.1" and config.mqtt.effective_port == 1883
    assert config.mqtt.formats == ["sparkplug", "json"]
    assert config.mqtt.json_topics.prefix == "focas"
    assert config.resolved_state_dir == DEFAULT_STATE_DIR
    assert config.warnings == []


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


def test_literal_password_is_refused_with_the_reason() -> None:
    problems = problems_of(MINIMAL.replace("host: broker", "host: broker\n  username: u\n  password: hunter2"))
    assert len(problems) == 1
    assert problems[0].startswith("mqtt.password: secrets do not belong in the config file")
    assert "password_env" in problems[0] and "hunter2" not in problems[0]


def test_password_from_environment() -> None:
    text = MINIMAL.replace("host: broker", "host: broker\n  username: u\n  password_env: MQTT_PASSWORD")
    config = parse(text, {"MQTT_PASSWORD": "s3cret"})
    assert config.mqtt.read_password({"MQTT_PASSWORD": "s3cret"}) == "s3cret"
    assert "s3cret" not in repr(config)
    assert problems_of(text, {}) == ["mqtt.password_env: environment variable MQTT_PASSWORD is not set (line 5)"]


def test_password_from_file(tmp_path: Path) -> None:
    secret = tmp_path / "pw"
    secret.write_text("from-file\n")
    text = MINIMAL.replace("host: broker", f"host: broker\n  username: u\n  password_file: {secret}")
    assert parse(text).mqtt.read_password({}) == "from-file"
    missing = text.replace(str(secret), str(tmp_path / "nope"))
    (problem,) = problems_of(missing)
    assert problem.startswith("mqtt.password_file: cannot read")


def test_password_needs_username_and_only_one_source() -> None:
    assert problems_of(MINIMAL.replace("host: broker", "host: broker\n  password_env: X"), {"X": "1"}) == [
        "mqtt.username: a password needs a username (line 2)"]
    both = MINIMAL.replace("host: broker", "host: broker\n  username: u\n  password_env: X\n  password_file: /x")
    assert problems_of(both, {"X": "1"}) == [
        "mqtt.password_file: give password_env or password_file, not both (line 6)"]


def test_sparkplug_section_required_for_sparkplug_format() -> None:
    text = "mqtt: {host: b}\nmachines: [{id: m, host: h}]\n"
    assert problems_of(text) == [
        "mqtt.sparkplug: required (group_id, edge_node_id) when formats includes sparkplug (line 1)"]
    assert parse("mqtt: {host: b, formats: [json]}\nmachines: [{id: m, host: h}]\n").mqtt.sparkplug is None
    assert problems_of("mqtt: {host: b, formats: []}\nmachines: [{id: m, host: h}]\n") == [
        "mqtt.formats: at least one of sparkplug, json (line 1)"]


@pytest.mark.parametrize("bad", ["a/b", "a#", "+", ""])
def test_machine_ids_follow_sparkplug_rules(bad: str) -> None:
    (problem,) = problems_of(MINIMAL.replace("id: m1", f"id: '{bad}'"))
    assert problem.startswith("machines[0].id: ")


def test_duplicate_machine_ids_ignoring_case_even_beside_other_errors() -> None:
    problems = problems_of("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: Mill, host: h}
          - {id: mill, host: h, timezone: Nowhere/Land}
    """)
    assert any(p.startswith("machines[1].id: 'mill' is already the id of machines[0]") for p in problems)
    assert any(p.startswith("machines[1].timezone") for p in problems)


def test_history_depth_clamped_with_a_warning() -> None:
    config = parse(MINIMAL + "alarms: {mode: ActivePlusHistory, history_depth: 400}\n")
    assert config.alarms.history_depth == 250
    depth_warnings = [w for w in config.warnings if "history_depth" in w]
    assert len(depth_warnings) == 1
    assert depth_warnings[0].startswith("alarms.history_depth: 400 is outside 1..250")
    low = parse(MINIMAL.replace("host: 10.0.0.1", "host: 10.0.0.1\n    alarms: {history_depth: 0}"))
    assert low.alarms_for(low.machines[0]).history_depth == 1
    assert low.warnings[0].startswith("machines[0].alarms.history_depth: 0")


def _machine_with_poll(poll: str) -> str:
    return MINIMAL + "    poll:\n" + textwrap.indent(textwrap.dedent(poll), "      ")


def test_poll_plan_forms() -> None:
    config = parse(_machine_with_poll("""
        periods: {status: 100ms, macros: 2, pmc: 1.5s, params: 1m, diags: 1h}
        macros: [500, "510-512", {first: 600, last: 601, name_prefix: Tool/Life, deadband: 0.5}]
        pmc:
          - {area: D, range: D2204-D2207, data_type: word, name: Overrides}
          - {area: R, range: 100-101}
          - {area: r, start: 10, end: 13, data_type: long}
        params: [6712, {number: 1815, axis: 2}]
        diags: [{number: 980, axis: 1, name: Servo/Error}]
    """))
    poll = config.machines[0].poll
    assert (poll.periods.status, poll.periods.macros, poll.periods.pmc) == (0.1, 2.0, 1.5)
    assert (poll.periods.params, poll.periods.diags) == (60.0, 3600.0)
    assert [list(m.numbers) for m in poll.macros] == [[500], [510, 511, 512], [600, 601]]
    assert poll.macros[2].metric_name(601) == "Tool/Life/601"
    word = poll.pmc[0].target
    assert (word.area, word.start, word.end, word.data_type) == ("D", 2204, 2207, PmcType.WORD)
    assert poll.pmc[0].addresses() == [2204, 2206]
    assert poll.pmc[0].metric_name(2206) == "Overrides/D2206"
    assert poll.pmc[1].metric_name(101) == "PMC/R101"
    assert poll.pmc[2].target.end == 13 and poll.pmc[2].addresses() == [10]
    assert poll.params[1].metric_name("Param") == "Param/1815/2"
    assert poll.diags[0].metric_name("Diag") == "Servo/Error"


def test_paths_expand_to_one_device_per_path() -> None:
    two_paths = MINIMAL + "    paths: 2\n"
    config = parse(two_paths)
    assert [(d.id, d.path) for d in config.devices()] == [("m1", 1), ("m1-path2", 2)]
    assert config.machine("m1-path2").host == "10.0.0.1"
    clash = problems_of(two_paths + "  - {id: m1-path2, host: 10.0.0.2}\n")
    assert any("its path 2 is the device 'm1-path2', already a machine id" in p for p in clash), clash
    packed = problems_of(MINIMAL.replace("    host: 10.0.0.1\n",
                                         "    transport: packed\n    address: unix:/run/x.sock\n    paths: 2\n"))
    assert any("paths: only for transport focas" in p for p in packed), packed


def test_numbered_reads_for_all_axes() -> None:
    config = parse(_machine_with_poll("""
        params: [{number: 1850, axis: all}]
        diags: [{number: 308, axis: ALL, name: Servo/Temperature}]
    """))
    poll = config.machines[0].poll
    assert (poll.params[0].axis, poll.diags[0].axis) == (-1, -1)
    assert poll.params[0].metric_name("Param") == "Param/1850"
    assert poll.diags[0].metric_name("Diag") == "Servo/Temperature"


@pytest.mark.parametrize(
    ("poll", "expected"),
    [
        ("pmc: [{range: D2204-D2206, data_type: word}]",
         "machines[0].poll.pmc[0].range: D2204-D2206 is 3 bytes, not a whole number of word (2-byte) elements"),
        ("pmc: [{area: R, start: 5, end: 1}]", "machines[0].poll.pmc[0].end: end 1 before start 5"),
        ("pmc: [{start: 5}]", "machines[0].poll.pmc[0].area: required with start/end"),
        ("pmc: [{area: R}]", "machines[0].poll.pmc[0].range: required (e.g. range: R100-R103"),
        ("pmc: [{area: R, range: D1}]", "machines[0].poll.pmc[0].range: range 'D1' is in area D, but area is R"),
        ("pmc: [{range: R1, data_type: nibble}]", "machines[0].poll.pmc[0].data_type: "),
        ("macros: [abc]", "machines[0].poll.macros[0]: expected a macro number or range"),
        ("macros: [{first: 1, last: 2, name: X}]", "machines[0].poll.macros[0].name: a single name fits one"),
        ("macros: [500, {first: 500, name_prefix: Macro}]",
         "machines[0].poll.macros[1]: metric name 'Macro/500' is already used by macros[0]"),
        ("params: [{number: 6711, name: Status/Run}]",
         "machines[0].poll.params[0].name: 'Status/Run': the folder 'Status' is reserved"),
        ("params: [{number: 1, name: 'a//b'}]", "machines[0].poll.params[0].name: 'a//b' is not a metric name"),
        ("periods: {status: 10ms}", "machines[0].poll.periods.status: Input should be greater than or equal"),
        ("periods: {status: fast}", "machines[0].poll.periods.status: expected a duration"),
        ("positions: [sideways]", "machines[0].poll.positions[0]: "),
        ("params: [{number: 1850, axis: some}]", "machines[0].poll.params[0]: axis must be 0..32 or 'all', got 'some'"),
    ],
)
def test_poll_plan_errors(poll: str, expected: str) -> None:
    problems = problems_of(_machine_with_poll(poll))
    assert any(p.startswith(expected) for p in problems), problems


def test_packed_transport_addresses() -> None:
    config = parse("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, transport: packed, address: "unix:/run/x.sock"}
          - {id: b, transport: packed, address: "tcp:10.0.0.2:9000"}
          - {id: c, transport: packed, host: 10.0.0.3, port: 9001}
    """)
    assert [m.endpoint for m in config.machines] == ["unix:/run/x.sock", "tcp:10.0.0.2:9000", "tcp:10.0.0.3:9001"]
    problems = problems_of("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, transport: packed, address: "udp:x"}
          - {id: b, address: "tcp:h:1"}
          - {id: c}
          - {id: d, transport: serial, host: h}
    """)
    assert any(p.startswith("machines[0].address: expected tcp:HOST:PORT or unix:/PATH") for p in problems)
    assert "machines[1].address: only for transport packed; the focas transport uses host and port (line 5)" in problems
    assert "machines[2].host: required (line 6)" in problems
    assert any(p.startswith("machines[3].transport: ") for p in problems)


def test_max_subpackets_reaches_the_client_and_is_checked() -> None:
    config = parse("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, host: h}
          - {id: b, host: h, max_subpackets: 64}
    """)
    clients = [default_session(machine_settings(config, m)) for m in config.machines]
    assert [c.max_subpackets for c in clients] == [MAX_SUBPACKETS, 64]  # type: ignore[attr-defined]
    problems = problems_of("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, host: h, max_subpackets: 1}
          - {id: b, host: h, max_subpackets: 500}
          - {id: c, transport: packed, address: "tcp:h:1", max_subpackets: 8}
    """)
    assert any(p.startswith("machines[0].max_subpackets: ") and "2" in p for p in problems), problems
    assert any(p.startswith("machines[1].max_subpackets: ") and "128" in p for p in problems), problems
    assert ("machines[2].max_subpackets: only for transport focas (the packed surface has no subpackets) (line 6)"
            in problems), problems


def test_writes_policy_global_plus_machine() -> None:
    config = parse("""
        mqtt: {host: b, formats: [json]}
        writes:
          enabled: true
          allow: [{target: "macro:500-599", min: 0, max: 10}]
          rate_limit: {max_writes: 5, per_s: 1m}
        machines:
          - {id: a, host: h, writes: {allow: [{target: "pmc:R100-R199"}], rate_limit: {max_writes: 1, per_s: 1}}}
          - {id: b, host: h, writes: {enabled: false}}
          - {id: c, host: h}
    """)
    a, b, c = (config.write_policy(m) for m in config.machines)
    assert a.enabled and [r.target for r in a.allow] == ["macro:500-599", "pmc:R100-R199"]
    assert a.rate_limit.max_writes == 1 and c.rate_limit.per_s == 60.0
    assert not b.enabled and c.enabled
    assert a.reconnect_deadline_s == 10.0 and a.max_payload_bytes == 4096
    off = parse(MINIMAL + "writes: {allow: [{target: 'macro:500'}]}\n")
    assert not off.write_policy(off.machines[0]).enabled


def test_writes_errors() -> None:
    problems = problems_of(MINIMAL + """writes:
  allow:
    - {target: "diag:980"}
    - {target: "macro:1", min: 5, max: 1}
    - {target: "pmc:Q1"}
  rate_limit: {max_writes: 0}
""")
    assert any(p.startswith("writes.allow[0].target: 'diag:980': diag:980 is read-only") for p in problems)
    assert "writes.allow[1].max: max 1.0 below min 5.0 (line 11)" in problems
    assert any(p.startswith("writes.allow[2].target: 'pmc:Q1': unknown PMC area") for p in problems)
    assert any(p.startswith("writes.rate_limit.max_writes: ") for p in problems)


def test_state_dir_precedence() -> None:
    assert parse(MINIMAL, {"STATE_DIRECTORY": "/var/lib/x:/var/lib/y"}).resolved_state_dir == Path("/var/lib/x")
    explicit = parse(MINIMAL + "state_dir: /srv/edge\n", {"STATE_DIRECTORY": "/var/lib/x"})
    assert explicit.resolved_state_dir == Path("/srv/edge")


def test_other_sections() -> None:
    config = parse(MINIMAL + "spool: {max_bytes: 64MiB, max_age_s: 2d}\nhttp: {enabled: true, port: 9200}\n")
    assert config.spool.max_bytes == 64 * 1024 * 1024 and config.spool.max_age_s == 2 * 86400
    assert config.http.enabled and config.http.port == 9200 and config.http.healthy_share == 0.5
    assert parse(MINIMAL.replace("host: broker", "host: broker\n  protocol: 5")).mqtt.protocol == "5"
    assert any(p.startswith("mqtt.protocol") for p in problems_of(MINIMAL.replace(
        "host: broker", "host: broker\n  protocol: 4")))


def test_tls_files_must_exist(tmp_path: Path) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    config = parse(MINIMAL.replace("host: broker", f"host: broker\n  tls: {{ca_file: {ca}}}"))
    assert config.mqtt.tls is not None and config.mqtt.effective_port == 8883
    problems = problems_of(MINIMAL.replace("host: broker", f"host: broker\n  tls: {{key_file: {ca}}}"))
    assert problems == ["mqtt.tls.key_file: a client key needs cert_file too (line 4)"]


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


def test_poll_grid_takes_a_duration() -> None:
    config = parse(MINIMAL + "poll_grid_s: 30ms\n")
    assert config.poll_grid_s == config.poll_grid_step_s == 0.03


@pytest.mark.parametrize("setting", ["", "poll_grid_s: auto\n", "poll_grid_s: AUTO\n"])
def test_poll_grid_auto_is_half_the_fastest_period_capped_at_50_ms(setting: str) -> None:
    assert parse(MINIMAL + setting).poll_grid_s is None
    assert parse(MINIMAL + setting).poll_grid_step_s == 0.05  # default periods: status 250 ms
    fast = MINIMAL + "    poll: {periods: {status: 80ms}}\n" + setting
    assert parse(fast).poll_grid_step_s == pytest.approx(0.04)


def test_poll_grid_auto_follows_the_fastest_machine_of_the_fleet() -> None:
    text = MINIMAL + "    poll: {periods: {status: 1s}}\n  - {id: m2, host: 10.0.0.2, poll: {periods: {pmc: 60ms}}}\n"
    assert parse(text).poll_grid_step_s == pytest.approx(0.03)


@pytest.mark.parametrize("grid,message", [
    ("0", "greater than 0"),
    ("200ms", "less than or equal to 0.1"),
    ("soon", "expected a duration"),
])
def test_poll_grid_out_of_range_is_refused(grid: str, message: str) -> None:
    problems = problems_of(MINIMAL + f"poll_grid_s: {grid}\n")
    assert any("poll_grid_s" in p and message in p for p in problems), problems


def test_poll_grid_coarser_than_half_a_period_is_refused_naming_the_machine() -> None:
    text = MINIMAL + "    poll: {periods: {status: 80ms}}\npoll_grid_s: 50ms\n"
    problems = problems_of(text)
    assert any("poll_grid_s 0.05s is more than half of machine 'm1'" in p and "0.04s" in p for p in problems), problems
