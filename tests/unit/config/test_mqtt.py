"""`mqtt:`: the password from the environment or a file (never the file itself), Sparkplug ids, TLS files."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.unit.config.minimal import MINIMAL, parse, problems_of


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


def test_tls_files_must_exist(tmp_path: Path) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    config = parse(MINIMAL.replace("host: broker", f"host: broker\n  tls: {{ca_file: {ca}}}"))
    assert config.mqtt.tls is not None and config.mqtt.effective_port == 8883
    problems = problems_of(MINIMAL.replace("host: broker", f"host: broker\n  tls: {{key_file: {ca}}}"))
    assert problems == ["mqtt.tls.key_file: a client key needs cert_file too (line 4)"]


def test_default_json_prefix_names_the_gateway_so_two_gateways_never_share_retained_topics() -> None:
    from edge.service.settings import publish_settings

    first = parse(MINIMAL.replace("edge_node_id: n", "edge_node_id: line1"))
    second = parse(MINIMAL.replace("edge_node_id: n", "edge_node_id: line2"))
    assert first.mqtt.json_prefix == "focas/g/line1" and second.mqtt.json_prefix == "focas/g/line2"
    assert publish_settings(first).json_prefix == "focas/g/line1"
    old = parse(MINIMAL.replace("host: broker", "host: broker\n  json: {prefix: focas}"))
    assert old.mqtt.json_prefix == "focas"  # the migration: today's topics, set explicitly


def test_json_only_without_ids_is_named_by_the_host(monkeypatch: pytest.MonkeyPatch) -> None:
    from edge.service.settings import publish_settings

    monkeypatch.setattr("socket.gethostname", lambda: "cell-7")
    config = parse(MINIMAL.replace("  sparkplug: {group_id: g, edge_node_id: n}\n", "  formats: [json]\n"))
    assert config.mqtt.json_prefix == "focas/cell-7"
    assert publish_settings(config).client_id == "focas-edge-cell-7"
