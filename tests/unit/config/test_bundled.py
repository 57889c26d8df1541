"""The example configs and units shipped inside the wheel are exactly the repository's."""

from __future__ import annotations

from pathlib import Path

from edge.config.bundled import bundled

REPO = Path(__file__).resolve().parents[3]


def test_the_wheel_bundles_every_example_config_and_unit() -> None:
    assert {f.name for f in bundled("config")} == {p.name for p in (REPO / "config").glob("*.yaml")}
    assert {f.name for f in bundled("systemd")} == {p.name for p in (REPO / "systemd").iterdir()}
