"""Per-function routing config: fwlib_host beside a native machine, and the honest warning without it."""

from __future__ import annotations

import logging
import socket
from pathlib import Path

import pytest

from edge import ConfigError
from edge.cli import main
from edge.collect.poller import default_session
from edge.config import parse_config
from edge.focas.routed import LIBRARY, NATIVE, RoutedSession
from edge.service.settings import machine_settings

BASE = """
mqtt:
  host: broker
  sparkplug: {group_id: g, edge_node_id: n}
alarms: {mode: ActivePlusHistory}
machines:
  - id: m1
"""


def test_native_only_history_is_a_warning_saying_what_is_and_is_not_published() -> None:
    config = parse_config(BASE + "    host: 10.0.0.1\n", "t.yaml", {})
    [warning] = config.warnings
    assert warning.startswith("machines[0] (m1): alarms mode ActivePlusHistory on the native transport alone")
    assert "will NOT be published" in warning and "Plan/DroppedFunctions" in warning
    assert "derives from them at its poll rate" in warning and "fwlib_host" in warning


@pytest.mark.parametrize("machine", [
    "    host: 10.0.0.1\n    fwlib_host: 'unix:/run/focas-edge-fwlib/m1.sock'\n",
    "    transport: packed\n    address: 'unix:/run/focas-edge-fwlib/m1.sock'\n",
])
def test_no_warning_where_a_transport_has_the_history(machine: str) -> None:
    assert parse_config(BASE + machine, "t.yaml", {}).warnings == []


def test_check_config_prints_the_warning(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "edge.yaml"
    path.write_text(BASE + "    host: 10.0.0.1\n")
    assert main(["check-config", str(path), "--quiet"]) == 0
    assert "warning: machines[0] (m1): alarms mode ActivePlusHistory" in capsys.readouterr().err


def test_fwlib_host_only_beside_the_native_transport() -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(BASE + "    transport: packed\n    address: 'unix:/a.sock'\n    fwlib_host: 'unix:/b.sock'\n",
                     "t.yaml", {})
    assert any("fwlib_host" in p for p in caught.value.problems)
    with pytest.raises(ConfigError):
        parse_config(BASE + "    host: 10.0.0.1\n    fwlib_host: 'nowhere'\n", "t.yaml", {})


def test_a_machine_with_both_routes_each_function_native_first() -> None:
    config = parse_config(BASE + "    host: 10.0.0.1\n    fwlib_host: 'tcp:127.0.0.1:18193'\n", "t.yaml", {})
    session = default_session(machine_settings(config, config.machines[0]))
    assert isinstance(session, RoutedSession)
    assert session.route("ReadStatus") == NATIVE and session.route("ReadMacros") == NATIVE
    assert session.route("ReadAlarmHistory") == LIBRARY
    assert session.route("write_param") == LIBRARY and session.route("write_macro") == NATIVE
    assert session.route("ReadSpindleLoad") == NATIVE  # the packed surface lacks it; native has it
    assert session.capabilities.can("ReadAlarmHistory") and session.capabilities.can("write_param")


async def test_a_library_host_that_stays_down_is_one_warning_not_one_a_tick(caplog: pytest.LogCaptureFixture) -> None:
    with socket.socket() as probe:  # a port nothing listens on: every connect is refused
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = parse_config(BASE + f"    host: 10.0.0.1\n    fwlib_host: 'tcp:127.0.0.1:{port}'\n", "t.yaml", {})
    session = default_session(machine_settings(config, config.machines[0]))
    assert isinstance(session, RoutedSession)
    caplog.set_level(logging.DEBUG, logger="edge.focas.routed")
    for _ in range(5):  # the poller asks again on every tick that reads a library-routed function
        await session._connect_library()
    records = [r for r in caplog.records if r.name == "edge.focas.routed"]
    warnings = [r.getMessage() for r in records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and warnings[0].startswith("connect failed library host peer=")
    assert "only the functions routed to it fail" in warnings[0]
    assert sum(r.levelno == logging.DEBUG for r in records) == 4
