"""check-config --as-service finds what the service user could not read or write, and an unusable
state_dir stops `run` with exit 2 and one line."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from edge.cli import main
from edge.config import parse_config, service_access
from edge.config.service_access import Account, lookup_account, service_problems, state_dir_problem
from tests.unit.config.minimal import MINIMAL


@pytest.fixture
def other_user() -> str:
    try:
        account = lookup_account("nobody")
    except KeyError:
        pytest.skip("no user 'nobody' here")
    if account.uid == os.getuid():
        pytest.skip("running as nobody")
    return "nobody"


def tls_config(folder: Path, mode: int) -> Path:
    ca = folder / "ca.pem"
    ca.write_text("not checked here\n")
    ca.chmod(mode)
    config = folder / "edge.yaml"
    config.write_text(MINIMAL.replace("  host: broker", f"  host: broker\n  tls: {{ca_file: {ca}}}"))
    return config


def test_as_service_names_a_file_the_service_user_cannot_read(
        open_dir: Path, other_user: str, capsys: pytest.CaptureFixture[str]) -> None:
    config = tls_config(open_dir, 0o600)
    assert main(["check-config", str(config)]) == 0  # fine for whoever runs check-config
    capsys.readouterr()
    assert main(["check-config", "--as-service", "--service-user", other_user, str(config)]) == 2
    err = capsys.readouterr().err
    assert f"mqtt.tls.ca_file: user {other_user} cannot read {open_dir / 'ca.pem'}" in err
    (open_dir / "ca.pem").chmod(0o644)
    assert main(["check-config", "--as-service", "--service-user", other_user, str(config)]) == 0


def test_as_service_names_a_directory_the_service_user_cannot_enter(open_dir: Path, other_user: str) -> None:
    config = parse_config(tls_config(open_dir, 0o644).read_text())
    open_dir.chmod(0o700)
    assert service_problems(config, other_user) == [
        f"mqtt.tls.ca_file: user {other_user} cannot enter {open_dir} to read {open_dir / 'ca.pem'}"]


def test_as_service_refuses_a_state_dir_outside_the_units_state_directory(open_dir: Path, other_user: str) -> None:
    config = parse_config(MINIMAL + f"state_dir: {open_dir}\n")
    (problem,) = service_problems(config, other_user)
    assert problem.startswith(f"state_dir: {open_dir} is read-only for the service") and "ProtectSystem" in problem


def test_as_service_finds_an_unwritable_state_dir(
        open_dir: Path, other_user: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(service_access, "UNIT_STATE_DIR", open_dir)  # owned by us, 0755: not writable by others
    config = parse_config(MINIMAL + f"state_dir: {open_dir / 'sub'}\n")
    assert service_problems(config, other_user) == [f"state_dir: user {other_user} cannot write {open_dir}"]
    open_dir.chmod(0o777)
    assert service_problems(config, other_user) == []


def test_as_service_with_an_unknown_user(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    config = tmp_path / "edge.yaml"
    config.write_text(MINIMAL)
    assert main(["check-config", "--as-service", "--service-user", "no-such-user-x", str(config)]) == 2
    assert "service user 'no-such-user-x' does not exist" in capsys.readouterr().err


def test_the_service_user_is_checked_by_mode_bits() -> None:
    account = Account("svc", uid=12345, gids=frozenset({12345}))
    assert service_access.allowed(account, Path("/"), service_access.SEARCH)
    assert not service_access.allowed(account, Path("/"), service_access.WRITE)


def test_unusable_state_dir_fails_check_config_and_run_with_exit_2_and_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "edge.yaml"
    config.write_text(MINIMAL + "state_dir: /proc/nope\n")
    assert main(["check-config", str(config)]) == 2
    assert "state_dir: cannot create or write /proc/nope" in capsys.readouterr().err
    assert main(["run", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [f"focas-edge: {config}: state_dir: cannot create or write /proc/nope "
                                "(No such file or directory)"]


def test_state_dir_probe_leaves_nothing_behind(tmp_path: Path) -> None:
    assert state_dir_problem(tmp_path / "a" / "b") is None
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("")
    assert state_dir_problem(tmp_path / "file") == f"state_dir: {tmp_path / 'file'} is not a directory"


def test_as_service_names_a_state_file_left_by_root_unless_systemd_hands_it_over(
        open_dir: Path, other_user: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """StateDirectory= chowns the whole tree only when the directory itself is not the service's already."""
    if os.geteuid() != 0:
        pytest.skip("needs root to make files of two owners")
    account = lookup_account(other_user)
    monkeypatch.setattr(service_access, "UNIT_STATE_DIR", open_dir)
    left = open_dir / "sparkplug_bdseq.json"
    left.write_text("{}")
    left.chmod(0o600)
    config = parse_config(MINIMAL + f"state_dir: {open_dir}\n")
    assert service_problems(config, other_user) == []  # dir root's: systemd hands it all to the service
    os.chown(open_dir, account.uid, account.gid if account.gid is not None else -1)
    assert service_problems(config, other_user) == [
        f"state_dir: {left} belongs to root:root (mode -rw-------), so user {other_user} cannot read and write it "
        f"(left by a run as another user?); fix: chown -R {account.owner} {open_dir}"]


def test_as_service_names_a_port_the_service_may_not_bind(tmp_path: Path, other_user: str) -> None:
    config = parse_config(MINIMAL + f"state_dir: {service_access.UNIT_STATE_DIR}\nhttp: {{enabled: true, port: 80}}\n")
    (problem,) = [p for p in service_problems(config, other_user) if p.startswith("http")]
    assert problem.startswith("http.port: 80 is below") and "CapabilityBoundingSet=" in problem


def test_a_running_service_holding_state_dir_is_fine_as_the_service_and_refused_otherwise(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """check-config --as-service after an upgrade or before a reload meets the running service's own lock."""
    from edge.cli import check_config
    from edge.service.state_lock import Holder

    monkeypatch.setattr(check_config, "holder", lambda state_dir: Holder(4242, "focas-edge.service"))
    monkeypatch.setattr(check_config, "service_problems", lambda *args: [])
    config = parse_config(MINIMAL + f"state_dir: {tmp_path}\nhttp: {{enabled: true}}\n")
    notes: list[str] = []
    assert check_config.usability_problems(config, tmp_path / "edge.yaml", "focas-edge", notes) == []
    assert "in use by the running focas-edge.service (PID 4242)" in notes[0]
    (problem,) = check_config.usability_problems(config, tmp_path / "edge.yaml", None)
    assert "(PID 4242, focas-edge.service;" in problem and "systemctl stop focas-edge" in problem


def test_state_dir_made_meanwhile_by_another_gateway_is_no_problem(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Two gateways starting at once probe the same parent: the one that finds it made between its look and
    its mkdir must not refuse to start, and must not remove what it did not make."""
    shared = tmp_path / "state"
    shared.mkdir()
    real_exists = Path.exists
    monkeypatch.setattr(Path, "exists", lambda self: False if self == shared else real_exists(self))
    assert state_dir_problem(shared / "hall-a") is None
    assert real_exists(shared)
