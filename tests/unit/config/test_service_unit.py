"""check-config --as-service asks the installed unit, not the admin's shell, whether the service gets its password:
the variable from Environment=/EnvironmentFile=, the credential from a LoadCredential= whose source exists."""

from __future__ import annotations

from pathlib import Path

import pytest

from edge.config import service_unit
from edge.config.service_unit import CREDENTIALS_DIR, password_problems, read_unit

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def unit_dirs(tmp_path: Path) -> tuple[Path, Path]:
    """An /etc and a /lib unit directory, the shipped unit in the /lib one."""
    etc, lib = tmp_path / "etc", tmp_path / "lib"
    lib.mkdir()
    etc.mkdir()
    unit = (REPO / "systemd" / "focas-edge.service").read_text()
    (lib / "focas-edge.service").write_text(unit.replace("/etc/focas-edge/secrets.env", str(tmp_path / "secrets.env")))
    return etc, lib


def drop_in(directory: Path, name: str, text: str) -> None:
    folder = directory / "focas-edge.service.d"
    folder.mkdir(exist_ok=True)
    (folder / name).write_text(f"[Service]\n{text}\n")


def test_password_env_comes_from_the_units_environment_file(unit_dirs: tuple[Path, Path], tmp_path: Path) -> None:
    unit = read_unit(unit_dirs)
    (problem,) = password_problems("MQTT_PASSWORD", None, unit)
    assert problem.startswith("mqtt.password_env: the service does not get MQTT_PASSWORD")
    assert f"fix: put MQTT_PASSWORD=... in {tmp_path / 'secrets.env'}" in problem
    (tmp_path / "secrets.env").write_text("# the broker login\nMQTT_PASSWORD=s3cret\n")
    assert password_problems("MQTT_PASSWORD", None, read_unit(unit_dirs)) == []


def test_password_env_from_a_drop_in_environment_line(unit_dirs: tuple[Path, Path]) -> None:
    etc, _ = unit_dirs
    drop_in(etc, "password.conf", 'Environment="MQTT_PASSWORD=a b" OTHER=1')
    assert password_problems("MQTT_PASSWORD", None, read_unit(unit_dirs)) == []
    drop_in(etc, "zz-reset.conf", "Environment=")  # an empty assignment resets the list, as systemd does
    assert password_problems("MQTT_PASSWORD", None, read_unit(unit_dirs))


def test_a_credential_needs_a_load_credential_whose_source_exists(unit_dirs: tuple[Path, Path], tmp_path: Path) -> None:
    etc, _ = unit_dirs
    password = CREDENTIALS_DIR / "mqtt-password"
    (problem,) = password_problems(None, password, read_unit(unit_dirs))
    assert "focas-edge.service loads no credential 'mqtt-password'" in problem
    source = tmp_path / "credentials" / "mqtt-password"
    drop_in(etc, "credentials.conf", f"LoadCredential=mqtt-password:{source}")
    (problem,) = password_problems(None, password, read_unit(unit_dirs))
    assert problem == (f"mqtt.password_file: focas-edge.service loads credential 'mqtt-password' from {source} "
                       f"(LoadCredential=), which does not exist: systemd would refuse the start "
                       f"(status=243/CREDENTIALS); fix: install -m 0600 /dev/stdin {source}")
    source.parent.mkdir()
    source.write_text("s3cret\n")
    assert password_problems(None, password, read_unit(unit_dirs)) == []


def test_a_higher_directorys_drop_in_hides_the_same_name_below(unit_dirs: tuple[Path, Path], tmp_path: Path) -> None:
    etc, lib = unit_dirs
    drop_in(lib, "credentials.conf", f"LoadCredential=mqtt-password:{tmp_path / 'missing'}")
    drop_in(etc, "credentials.conf", "# disabled here")
    unit = read_unit(unit_dirs)
    assert unit is not None and unit.credentials == {}
    assert unit.files == [lib / "focas-edge.service", etc / "focas-edge.service.d" / "credentials.conf"]


def test_without_an_installed_unit_nothing_hands_over_a_password(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(service_unit, "UNIT_DIRS", (tmp_path,))
    assert read_unit() is None
    assert password_problems("MQTT_PASSWORD", None, None) == [
        "mqtt.password_env: no focas-edge.service is installed to give the service MQTT_PASSWORD"]
    assert password_problems(None, Path("/etc/focas-edge/password"), None) == []  # a plain file: read checks
