"""The systemd install: the unit runs as a user that can read its config, the TLS example's credential is
loaded, check-config --as-service finds what the service user could not read or write, and an unusable
state_dir stops `run` with exit 2 and one line."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge.cli import main
from edge.config import parse_config, service_access
from edge.config.bundled import bundled
from edge.config.service_access import Account, lookup_account, service_problems, state_dir_problem
from tests.unit.test_config import MINIMAL

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "systemd" / "focas-edge.service"


def unit_values(text: str, key: str) -> list[str]:
    return [line.partition("=")[2].strip() for line in text.splitlines() if line.startswith(f"{key}=")]


def test_unit_runs_as_the_packages_user_not_a_dynamic_one() -> None:
    """DynamicUser= cannot read a root-owned ConfigurationDirectory=; the static user's group can."""
    text = UNIT.read_text()
    assert unit_values(text, "DynamicUser") in ([], ["no"])
    assert unit_values(text, "User") == ["focas-edge"] and unit_values(text, "Group") == ["focas-edge"]
    assert unit_values(text, "ConfigurationDirectory") == []  # the package owns /etc/focas-edge, group-readable
    assert unit_values(text, "StateDirectory") == ["focas-edge"]


def test_every_credential_an_example_reads_is_loaded_by_a_shipped_unit_or_drop_in() -> None:
    loaded = {value.partition(":")[0] for unit in (REPO / "systemd").iterdir()
              for value in unit_values(unit.read_text(), "LoadCredential")}
    wanted = {name for example in (REPO / "config").glob("*.yaml")
              for name in re.findall(r"/run/credentials/focas-edge\.service/([\w.-]+)", example.read_text())}
    assert "mqtt-password" in wanted  # config/tls-broker.yaml
    assert wanted <= loaded


def test_the_wheel_bundles_every_example_config_and_unit() -> None:
    assert {f.name for f in bundled("config")} == {p.name for p in (REPO / "config").glob("*.yaml")}
    assert {f.name for f in bundled("systemd")} == {p.name for p in (REPO / "systemd").iterdir()}


@pytest.fixture
def open_dir() -> Iterator[Path]:
    """A directory any user can enter (pytest's tmp_path is 0700, which would hide everything in it)."""
    path = Path(tempfile.mkdtemp(prefix="focas-edge-svc-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path)


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


@pytest.fixture(scope="module")
def deb(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`make deb`'s script, built into a temporary directory (about 30 s: a venv and its dependencies)."""
    if shutil.which("dpkg-deb") is None or shutil.which("dpkg") is None:
        pytest.skip("dpkg-deb is not installed")
    out = tmp_path_factory.mktemp("deb")
    env = {**os.environ, "DEB_BUILD_DIR": str(out / "build"), "DEB_OUT_DIR": str(out)}
    result = subprocess.run(["bash", str(REPO / "scripts" / "build-deb.sh")], env=env, capture_output=True,
                            text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    return Path(result.stdout.strip().splitlines()[-1])


def deb_field(deb: Path, field: str) -> str:
    return subprocess.run(["dpkg-deb", "--field", str(deb), field], capture_output=True, text=True,
                          check=True).stdout.strip()


def test_deb_carries_the_venv_command_units_and_example_config(deb: Path) -> None:
    listing = subprocess.run(["dpkg-deb", "--contents", str(deb)], capture_output=True, text=True,
                             check=True).stdout
    entries = {line.split()[5].removeprefix("."): line for line in listing.splitlines()}
    assert entries["/usr/bin/focas-edge"].endswith("-> /opt/focas-edge/bin/focas-edge")
    assert "/opt/focas-edge/bin/focas-edge" in entries
    for unit in (REPO / "systemd").glob("*.service"):
        assert f"/lib/systemd/system/{unit.name}" in entries
    assert entries["/etc/focas-edge/edge.yaml"].startswith("-rw-r-----")
    assert any(e.endswith("/site-packages/edge/bundled/systemd/focas-edge.service") for e in entries)
    assert any(e.endswith("/site-packages/pydantic_core/__init__.py") for e in entries)
    assert "/usr/share/doc/focas-edge/copyright" in entries
    arch = subprocess.run(["dpkg", "--print-architecture"], capture_output=True, text=True, check=True).stdout
    assert deb_field(deb, "Architecture") == arch.strip() and deb_field(deb, "Package") == "focas-edge"
    assert "adduser" in deb_field(deb, "Depends")


def test_deb_scripts_enable_nothing_and_the_venv_points_at_opt(deb: Path, tmp_path: Path) -> None:
    subprocess.run(["dpkg-deb", "--raw-extract", str(deb), str(tmp_path)], check=True)
    assert (tmp_path / "DEBIAN" / "conffiles").read_text().split() == ["/etc/focas-edge/edge.yaml"]
    for script in ("postinst", "prerm", "postrm"):
        commands = [line for line in (tmp_path / "DEBIAN" / script).read_text().splitlines()
                    if not line.strip().startswith(("#", "echo"))]  # what is run, not what is advised
        calls = re.findall(r"systemctl ([\w-]+)", "\n".join(commands))
        assert not {"enable", "start", "restart"} & set(calls), (script, calls)
    shebang = (tmp_path / "opt/focas-edge/bin/focas-edge").read_text().splitlines()[0]
    assert re.fullmatch(r"#!/opt/focas-edge/bin/python3?", shebang), shebang
    assert str(tmp_path) not in (tmp_path / "opt/focas-edge/pyvenv.cfg").read_text()
