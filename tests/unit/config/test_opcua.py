"""`opcua:`: off by default, users' secrets as for MQTT, warnings for None and anonymous, the missing extra."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import get_args

import pytest

from edge.cli import check_config
from edge.config.opcua import SecurityMode
from edge.config.service_access import named_files
from edge.opcua.settings import SECURITY_MODES
from tests.unit.config.minimal import MINIMAL, parse, problems_of

USERS = "opcua:\n  enabled: true\n  users:\n    - {username: scada, password_env: OPCUA_PW}\n"


def test_off_by_default_and_reads_nothing() -> None:
    config = parse(MINIMAL)
    assert config.opcua.enabled is False and config.warnings == []


def test_a_user_with_a_password_from_the_environment_or_a_file(tmp_path: Path) -> None:
    config = parse(MINIMAL + USERS, {"OPCUA_PW": "s3cret"})
    assert config.opcua.read_users({"OPCUA_PW": "s3cret"}) == {"scada": "s3cret"}
    assert "s3cret" not in repr(config) and config.warnings == []
    assert problems_of(MINIMAL + USERS) == [
        "opcua.users[0].password_env: environment variable OPCUA_PW is not set (line 11)"]
    secret = tmp_path / "pw"
    secret.write_text("from-file\n")
    text = MINIMAL + USERS.replace("password_env: OPCUA_PW", f"password_file: {secret}")
    assert parse(text).opcua.read_users() == {"scada": "from-file"}
    assert ("opcua.users[0].password_file", secret) in named_files(parse(text))


@pytest.mark.parametrize(("section", "problem"), [
    ("opcua: {enabled: true}", "opcua: enabled with no users and allow_anonymous false: nobody could connect"),
    ("opcua: {users: [{username: a, password: hunter2}]}", "opcua.users[0].password: secrets do not belong"),
    ("opcua: {users: [{username: a}]}", "opcua.users[0]: Value error, user 'a': give exactly one of"),
    ("opcua: {security: [Basic128Rsa15]}", "opcua.security[0]: Input should be"),
    ("opcua: {security: []}", "opcua.security: List should have at least 1 item"),
    ("opcua: {path: focas}", "opcua.path: Value error, 'focas': expected an endpoint path"),
    ("opcua: {certificate_file: /nonexistent.der}", "opcua.certificate_file: Value error, no such file"),
    ("opcua: {prot: 1}", "opcua.prot: unknown key"),
])
def test_bad_sections_name_what_is_wrong(section: str, problem: str) -> None:
    problems = problems_of(MINIMAL + section)
    assert any(p.replace("Value error, ", "").startswith(problem.replace("Value error, ", "")) for p in problems), \
        problems
    assert "hunter2" not in " ".join(problems)


def test_none_security_and_anonymous_are_warned_about() -> None:
    text = MINIMAL + USERS + "  security: [Basic256Sha256-SignAndEncrypt, None]\n  allow_anonymous: true\n"
    warnings = parse(text, {"OPCUA_PW": "x"}).warnings
    assert len(warnings) == 2
    assert warnings[0].startswith("opcua.security lists None") and "stay encrypted" in warnings[0]
    assert warnings[1].startswith("opcua.allow_anonymous is true")
    alone = parse(MINIMAL + USERS + "  security: [None]\n", {"OPCUA_PW": "x"}).warnings
    assert "in clear text too" in alone[0]


def test_config_modes_are_the_servers() -> None:
    assert set(get_args(SecurityMode)) == set(SECURITY_MODES)


def test_check_config_names_the_missing_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "edge.yaml"
    path.write_text(MINIMAL + USERS)
    monkeypatch.setenv("OPCUA_PW", "x")
    monkeypatch.setattr(check_config, "missing_extra", lambda: "the OPC UA server needs the asyncua package")
    args = argparse.Namespace(config=str(path), quiet=True, as_service=False, service_user="focas-edge")
    assert check_config.run(args) == 2
    assert "opcua.enabled: the OPC UA server needs the asyncua package" in capsys.readouterr().err
    monkeypatch.setattr(check_config, "missing_extra", lambda: None)
    assert check_config.run(args) == 0
