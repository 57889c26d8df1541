"""`focas-edge acl CONFIG`: the broker ACL for a config that already exists."""

from __future__ import annotations

from pathlib import Path

import pytest

from edge.cli import EXIT_OK, EXIT_USAGE, main

CONFIG = """\
mqtt:
  host: 127.0.0.1
  username: gw3
  password_env: NOT_SET_HERE
  sparkplug: {group_id: hall-b, edge_node_id: gw-3}
machines:
  - {id: m1, host: 10.0.0.5}
"""


def test_acl_for_an_existing_config_names_its_ids_and_reads_no_secret(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "edge.yaml"
    config.write_text(CONFIG)
    assert main(["acl", str(config), "--users", "gw3:mes"]) == EXIT_OK
    acl = capsys.readouterr().out.splitlines()
    gateway, mes = acl[acl.index("user gw3") + 1:acl.index("user mes")], acl[acl.index("user mes") + 1:]
    assert "topic write spBv1.0/hall-b/DDATA/gw-3/+" in gateway
    assert "topic write spBv1.0/hall-b/DCMD/gw-3/+" in mes
    assert not any("CMD" in line for line in gateway if line.startswith("topic write"))


def test_acl_writes_a_file_once_and_refuses_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config, out = tmp_path / "edge.yaml", tmp_path / "mosquitto.acl"
    config.write_text(CONFIG)
    assert main(["acl", str(config), "-o", str(out)]) == EXIT_OK and "user mes" in out.read_text()
    assert main(["acl", str(config), "-o", str(out)]) == EXIT_USAGE
    assert "exists" in capsys.readouterr().err
    assert main(["acl", str(config), "--users", "same:same"]) == EXIT_USAGE
    assert "GATEWAY:MES" in capsys.readouterr().err
    config.write_text("mqtt: {host: 127.0.0.1}\nmachines: nope\n")
    assert main(["acl", str(config)]) == EXIT_USAGE
    assert "machines" in capsys.readouterr().err
