"""The library host's systemd unit: systemd-analyze verify in a throwaway root, and what it promises."""

from __future__ import annotations

import shutil
from pathlib import Path

from tests.integration.test_systemd import INSTALLED_BINARY, findings, systemd_analyze, unit_entries, values, verify

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "focas-edge-fwlib-host.service"
DAEMON_UNIT = UNIT.with_name("focas-edge.service")


def test_unit_serves_sockets_only_the_daemons_user_can_reach() -> None:
    entries = unit_entries(UNIT.read_text())
    daemon = unit_entries(DAEMON_UNIT.read_text())
    # Both run as the package's system user: the daemon reaches the 0600 sockets, nobody else does. A
    # DynamicUser could not read the root:focas-edge 0640 config either.
    assert values(entries, "Service", "DynamicUser") in ([], ["no"])
    assert values(daemon, "Service", "User") == values(entries, "Service", "User") == ["focas-edge"]
    assert values(daemon, "Service", "Group") == values(entries, "Service", "Group") == ["focas-edge"]
    assert values(entries, "Service", "RuntimeDirectory") == ["focas-edge-fwlib"]
    assert values(entries, "Service", "RuntimeDirectoryMode") == ["0700"]
    assert values(entries, "Service", "RestartPreventExitStatus") == ["2"]
    assert values(entries, "Service", "Type") == ["notify"]
    assert "fwlib-host --config /etc/focas-edge/fwlib-host.yaml" in values(entries, "Service", "ExecStart")[0]


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    tool = systemd_analyze()
    stub = tmp_path / INSTALLED_BINARY.lstrip("/")
    stub.parent.mkdir(parents=True)
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    units = tmp_path / "etc/systemd/system"
    units.mkdir(parents=True)
    unit = units / UNIT.name
    unit.write_text(UNIT.read_text().replace(INSTALLED_BINARY, str(stub)))
    shutil.copy(DAEMON_UNIT, units / DAEMON_UNIT.name)
    result = verify(tool, unit)
    assert result.returncode == 0 and findings(result) == [], result.stderr
