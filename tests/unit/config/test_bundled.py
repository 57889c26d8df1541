"""The example configs and units shipped inside the wheel are exactly the repository's."""

from __future__ import annotations

from pathlib import Path

from edge.config.bundled import PACKAGED_COMMAND, bundled, unit_for

REPO = Path(__file__).resolve().parents[3]


def test_the_wheel_bundles_every_example_config_and_unit() -> None:
    assert {f.name for f in bundled("config")} == {p.name for p in (REPO / "config").glob("*.yaml")}
    assert {f.name for f in bundled("systemd")} == {p.name for p in (REPO / "systemd").iterdir()}


def test_units_written_for_another_installation_run_its_command() -> None:
    shipped = next(f for f in bundled("systemd") if f.name == "focas-edge.service").read_text()
    venv = unit_for(shipped, "/srv/edge/venv/bin/focas-edge")
    assert "ExecStart=/srv/edge/venv/bin/focas-edge run --config /etc/focas-edge/edge.yaml" in venv
    assert PACKAGED_COMMAND not in venv and "\nProtectHome=yes\n" in venv
    home = unit_for(shipped, "/home/ops/venv/bin/focas-edge")  # ProtectHome=yes would hide it from the service
    assert "\nProtectHome=read-only\n" in home and "\nProtectHome=yes\n" not in home
    module = unit_for(shipped, "/usr/bin/python3 -m edge")
    assert "ExecStart=/usr/bin/python3 -m edge run --config /etc/focas-edge/edge.yaml" in module
