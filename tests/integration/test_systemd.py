"""The systemd unit (checked by systemd-analyze in a throwaway root) and the daemon's sd_notify protocol.

The notify test plays systemd: it binds an AF_UNIX datagram socket, starts `focas-edge run` with
NOTIFY_SOCKET and WATCHDOG_USEC set, and reads what the daemon says: READY=1, WATCHDOG=1 pings,
RELOADING=1 then READY=1 on SIGHUP, STOPPING=1 on SIGTERM, then exit 0.
"""

from __future__ import annotations

import asyncio
import shutil
import signal
import socket
import subprocess
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from edge.collect.settings import MachineSettings
from edge.config import parse_config
from edge.focas import items as it
from edge.focas.client import FocasClient
from edge.focas.session import ItemResult
from edge.service.daemon import Daemon
from edge.service.sdnotify import SystemdNotifier
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.test_signals import DaemonProcess, daemon_config

pytestmark = pytest.mark.integration

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "focas-edge.service"
INSTALLED_BINARY = "/opt/focas-edge/bin/focas-edge"


def unit_entries(text: str) -> list[tuple[str, str, str]]:
    """(section, key, value) in file order; repeated keys stay separate, as systemd reads them."""
    entries, section = [], ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, _, value = line.partition("=")
        entries.append((section, key.strip(), value.strip()))
    return entries


def values(entries: list[tuple[str, str, str]], section: str, key: str) -> list[str]:
    return [v for s, k, v in entries if s == section and k == key]


def test_unit_declares_notify_watchdog_restart_and_hardening() -> None:
    entries = unit_entries(UNIT.read_text())

    def one(key: str) -> str:
        (value,) = values(entries, "Service", key)
        return value

    assert one("Type") == "notify" and one("NotifyAccess") == "main"
    assert one("WatchdogSec").rstrip("s").isdigit()
    assert one("Restart") == "on-failure"
    assert one("User") == "focas-edge" and one("Group") == "focas-edge"  # the package's system user
    assert one("StateDirectory") == "focas-edge"
    assert one("EnvironmentFile").lstrip("-") == "/etc/focas-edge/secrets.env"
    assert one("ExecStart").startswith(f"{INSTALLED_BINARY} run --config /etc/focas-edge/edge.yaml")
    assert "-HUP $MAINPID" in one("ExecReload")
    for key, expected in {"NoNewPrivileges": "yes", "ProtectSystem": "strict", "ProtectHome": "yes",
                          "PrivateTmp": "yes", "CapabilityBoundingSet": ""}.items():
        assert one(key) == expected, key
    families = set(one("RestrictAddressFamilies").split())
    assert families == {"AF_INET", "AF_INET6", "AF_UNIX"}  # broker + CNCs, NOTIFY_SOCKET and unix: CNCs
    assert "@system-service" in values(entries, "Service", "SystemCallFilter")
    assert values(entries, "Install", "WantedBy") == ["multi-user.target"]


@pytest.fixture
def throwaway_root(tmp_path: Path) -> Iterator[Path]:
    """A root with the unit installed as a package would, its commands pointed at stubs inside the root."""
    root = tmp_path / "root"
    stub = root / INSTALLED_BINARY.lstrip("/")
    stub.parent.mkdir(parents=True)
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    kill_stub = root / "usr/bin/kill"
    kill_stub.parent.mkdir(parents=True)
    shutil.copy(stub, kill_stub)
    units = root / "etc/systemd/system"
    units.mkdir(parents=True)
    text = UNIT.read_text().replace(INSTALLED_BINARY, str(stub))
    text = text.replace("ExecReload=/bin/kill ", f"ExecReload={kill_stub} ")
    (units / UNIT.name).write_text(text)
    (root / "etc/focas-edge").mkdir(parents=True)
    yield root


def systemd_analyze() -> str:
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed")
    return tool


def verify(tool: str, unit: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([tool, "verify", "--man=no", str(unit)], capture_output=True, text=True, timeout=60,
                          check=False)


def findings(result: subprocess.CompletedProcess[str]) -> list[str]:
    """What verify said about our unit, less the libseccomp-vs-systemd version noise about unknown syscalls."""
    return [line for line in result.stderr.splitlines()
            if line.strip() and "Failed to parse system call" not in line]


def test_systemd_analyze_verify_accepts_the_installed_unit(throwaway_root: Path) -> None:
    tool = systemd_analyze()
    unit = throwaway_root / "etc/systemd/system" / UNIT.name
    result = verify(tool, unit)
    assert result.returncode == 0 and findings(result) == [], result.stderr


def test_systemd_analyze_verify_catches_a_broken_unit(throwaway_root: Path) -> None:
    """The check above can fail: a misspelt directive and a missing binary are reported."""
    tool = systemd_analyze()
    unit = throwaway_root / "etc/systemd/system" / UNIT.name
    broken = unit.read_text().replace("ProtectHome=yes", "ProtectHomme=yes")
    (throwaway_root / INSTALLED_BINARY.lstrip("/")).unlink()
    unit.write_text(broken)
    result = verify(tool, unit)
    text = "\n".join(findings(result))
    assert "ProtectHomme" in text and "not executable" in text, result.stderr


def test_systemd_analyze_security_rates_the_unit_well(throwaway_root: Path) -> None:
    tool = systemd_analyze()
    unit = throwaway_root / "etc/systemd/system" / UNIT.name
    result = subprocess.run([tool, "security", "--offline=yes", "--threshold=30", str(unit)],
                            capture_output=True, text=True, timeout=60, check=False)
    if "--offline" in result.stderr and "unrecognized" in result.stderr:
        pytest.skip("this systemd-analyze has no offline security check")
    # exposure 0.0 (best) .. 10.0; threshold 30 = 3.0: anything above "OK" fails the command.
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr


class NotifySocket:
    """The systemd side of sd_notify: a datagram socket that collects every message."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.setblocking(False)
        self.messages: list[set[str]] = []

    def drain(self) -> list[set[str]]:
        while True:
            try:
                data = self.sock.recv(4096)
            except BlockingIOError:
                return self.messages
            self.messages.append(set(data.decode().split("\n")))

    def count(self, field: str) -> int:
        return sum(1 for message in self.drain() if field in message)

    def index(self, field: str, after: int = -1) -> int:
        return next(i for i, m in enumerate(self.drain()) if i > after and field in m)

    def close(self) -> None:
        self.sock.close()


async def test_notify_ready_watchdog_reloading_stopping(mosquitto: Mosquitto, tmp_path: Path) -> None:
    notify = NotifySocket(tmp_path / "notify.sock")
    daemon: DaemonProcess | None = None
    try:
        async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
            config = tmp_path / "edge.yaml"
            config.write_text(daemon_config(mosquitto, tmp_path / "state", {"m1": fleet[0].port}))
            daemon = DaemonProcess(config, env={"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "400000"})
            await daemon.start()
            await async_wait_for(lambda: notify.count("READY=1") >= 1, 20, message="READY=1")
            ready = notify.index("READY=1")
            assert any(f.startswith("STATUS=") for f in notify.messages[ready])
            await async_wait_for(lambda: notify.count("WATCHDOG=1") >= 3, 10, message="3 WATCHDOG=1 pings")
            assert notify.index("WATCHDOG=1") > ready, "pings start after READY"

            daemon.signal(signal.SIGHUP)
            await async_wait_for(lambda: notify.count("RELOADING=1") >= 1, 10, message="RELOADING=1")
            reloading = notify.index("RELOADING=1")
            await async_wait_for(lambda: notify.count("READY=1") >= 2, 10, message="READY=1 after the reload")
            assert notify.index("READY=1", reloading) > reloading

            pings = notify.count("WATCHDOG=1")
            await async_wait_for(lambda: notify.count("WATCHDOG=1") > pings + 1, 10,
                                 message="pings continue after the reload")
            daemon.signal(signal.SIGTERM)
            assert await daemon.wait(10) == 0, daemon.output()
            notify.drain()
            assert any("STOPPING=1" in m for m in notify.messages), notify.messages[-3:]
            stopping = notify.index("STOPPING=1")
            assert stopping > reloading
    finally:
        if daemon is not None:
            await daemon.kill()
        notify.close()


class WedgingClient(FocasClient):
    """A transport with a bug: once wedged, a batch never returns (it bypasses every timeout)."""

    wedged = False

    async def batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        if self.wedged:
            await asyncio.Event().wait()
        return await super().batch(items)


async def test_watchdog_is_withheld_while_a_poll_loop_is_wedged(
        mosquitto: Mosquitto, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """A poll loop that stops making progress stops the pings, so systemd restarts the daemon."""
    notify = NotifySocket(tmp_path / "notify.sock")
    monkeypatch.setenv("WATCHDOG_USEC", "200000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    clients: list[WedgingClient] = []

    def session_factory(machine: MachineSettings) -> WedgingClient:
        client = WedgingClient("127.0.0.1", int(machine.endpoint.rsplit(":", 1)[1]), timeout=0.2, connect_timeout=0.2)
        clients.append(client)
        return client

    def withheld() -> int:
        notify.drain()
        return sum(1 for r in caplog.records if "watchdog withheld" in r.getMessage())

    try:
        async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
            text = daemon_config(mosquitto, tmp_path / "state", {"m1": fleet[0].port}).replace(
                "request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.3",
                "request_s: 0.2, connect_s: 0.2, backoff_initial_s: 0.1, backoff_max_s: 0.1")
            daemon = Daemon(parse_config(text), session_factory=session_factory,
                            notifier=SystemdNotifier(str(notify.path)))
            task = asyncio.create_task(daemon.run())
            try:
                await async_wait_for(lambda: notify.count("WATCHDOG=1") >= 3, 10, message="pings while healthy")
                assert withheld() == 0
                clients[0].wedged = True
                await async_wait_for(lambda: withheld() >= 1, 10, message="the watchdog withheld")
                pings = notify.count("WATCHDOG=1")
                await async_wait_for(lambda: withheld() >= 4, 10, message="still withheld")
                assert notify.count("WATCHDOG=1") == pings
                assert not daemon.healthy()
            finally:
                daemon.request_stop()
                assert await asyncio.wait_for(task, 15) == 0
    finally:
        notify.close()


def test_notifier_never_blocks_when_the_reader_lags(tmp_path: Path) -> None:
    """A full datagram queue (systemd busy) drops the notification instead of stalling the event loop."""
    notify = NotifySocket(tmp_path / "notify.sock")
    notifier = SystemdNotifier(str(notify.path))
    try:
        sent = [notifier.watchdog() for _ in range(500)]  # far beyond the default queue length (10)
        assert sent[0] is True and sent[-1] is False
        assert 0 < notify.count("WATCHDOG=1") < 500
        assert notifier.watchdog() is True  # the queue drained: notifications flow again
    finally:
        notifier.close()
        notify.close()


async def test_bad_config_exits_2_which_the_unit_does_not_restart(tmp_path: Path) -> None:
    config = tmp_path / "edge.yaml"
    config.write_text("mqtt: {host: localhost, port: 0}\nmachines: []\n")
    daemon = DaemonProcess(config)
    try:
        await daemon.start()
        assert await daemon.wait(30) == 2, daemon.output()
    finally:
        await daemon.kill()
    assert "machines" in daemon.output()
    (prevent,) = values(unit_entries(UNIT.read_text()), "Service", "RestartPreventExitStatus")
    assert set(prevent.split()) == {"2", "243"}  # 243: systemd's CREDENTIALS, a LoadCredential= source missing
