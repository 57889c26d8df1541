"""The systemd install: the unit runs as a user that can read its config, the TLS example's credential is
loaded, and the .deb carries the venv, the units and the example config without enabling anything.
(check-config --as-service and the state_dir checks: tests/unit/config/test_service_access.py.)"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

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
    # A minimal Debian has no python3: the venv's bin/python -> /usr/bin/python3 of the minor version it was
    # built with must come from Depends; procps for the unit's ExecReload=/bin/kill (make systemd-check installs
    # into a minbase root without them).
    depends = [d.strip() for d in deb_field(deb, "Depends").split(",")]
    built_with = subprocess.run([os.environ.get("DEB_PYTHON", "/usr/bin/python3"), "-c",
                                 "import sys; print(*sys.version_info[:2])"], capture_output=True, text=True,
                                check=True).stdout.split()
    major, minor = int(built_with[0]), int(built_with[1])
    assert (major, minor) >= (3, 11)
    assert f"python3 (>= {major}.{minor})" in depends and f"python3 (<< {major}.{minor + 1})" in depends, depends
    assert {"adduser", "procps"} <= set(depends)


def test_postinst_makes_the_home_before_adduser_and_gives_the_state_back() -> None:
    """adduser warns about a --no-create-home home that does not exist; a run as root leaves root's files."""
    lines = [line.strip() for line in (REPO / "packaging/deb/postinst").read_text().splitlines()
             if not line.strip().startswith("#")]
    made = next(i for i, line in enumerate(lines) if line.startswith("install -d") and "/var/lib/focas-edge" in line)
    adduser = next(i for i, line in enumerate(lines) if line.startswith("adduser "))
    assert made < adduser
    assert "chown -Rh focas-edge:focas-edge /var/lib/focas-edge" in lines


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
