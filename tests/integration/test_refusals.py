"""Whatever `run` refuses at start, `check-config` refuses first, as the same user, naming the same problem.

Each case is walked through both commands as real processes: `check-config` exits 2 listing the problem,
`run` exits 2 with that problem as its one line on stderr, no traceback (the unit does not restart on 2).
Cases: an unusable state_dir, a state file left by another user (a `run` as root before the service),
the status HTTP port taken, a missing password file or variable, the state_dir lock held, a config file
the user cannot read. No broker is needed: every refusal comes before the first connect.
"""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.integration.test_signals import focas_edge_command

pytestmark = pytest.mark.integration

BASE = """\
mqtt:
  host: 127.0.0.1
  port: 1
  sparkplug: {{group_id: g, edge_node_id: n}}
{mqtt_extra}state_dir: {state_dir}
{extra}machines:
  - {{id: m1, host: 127.0.0.1, port: 1}}
"""


@dataclass
class Case:
    config: Path
    expected: str  # what the problem line must name
    user: list[str]  # the command prefix that runs both commands as the same (other) user, or []


def as_nobody() -> list[str]:
    """Run as user nobody (we are root): the realistic other user for files root left behind."""
    prefix = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups"]
    probe = subprocess.run([*prefix, *focas_edge_command(), "--version"], capture_output=True, timeout=60,
                           check=False)
    if shutil.which("setpriv") is None or probe.returncode != 0:
        pytest.skip("cannot run focas-edge as user nobody here")
    return prefix


def write_config(folder: Path, state_dir: Path, extra: str = "", mqtt_extra: str = "") -> Path:
    config = folder / "edge.yaml"
    config.write_text(BASE.format(state_dir=state_dir, extra=extra, mqtt_extra=mqtt_extra))
    config.chmod(0o644)
    return config


def state_dir_unusable(folder: Path) -> Case:
    return Case(write_config(folder, Path("/proc/nope")), "state_dir: cannot create or write /proc/nope", [])


def state_file_of_another_user(folder: Path) -> Case:
    """A `focas-edge run` as root left a root-owned 0600 file in the service user's state_dir."""
    state = folder / "state"
    state.mkdir()
    left = state / "sparkplug_bdseq.json"
    left.write_text('{"last": 7}')
    left.chmod(0o600)
    if os.geteuid() == 0:
        os.chown(state, 65534, 65534)
        return Case(write_config(folder, state), f"state_dir: {left} belongs to root:", as_nobody())
    left.chmod(0o400)  # not root: a file of our own we may not write stands in for it
    return Case(write_config(folder, state), f"state_dir: {left} belongs to", [])


def port_taken(folder: Path, listener: socket.socket) -> Case:
    port = listener.getsockname()[1]
    config = write_config(folder, folder / "state", f"http: {{enabled: true, host: 127.0.0.1, port: {port}}}\n")
    return Case(config, f"http.port: 127.0.0.1:{port} is already in use", [])


def opcua_port_taken(folder: Path, listener: socket.socket) -> Case:
    """The OPC UA server's port, refused the same way (the daemon does not run on without the server)."""
    pytest.importorskip("asyncua", reason="the focas-edge[opcua] extra is not installed")
    port = listener.getsockname()[1]
    (folder / "opcua.password").write_text("secret\n")
    config = write_config(folder, folder / "state",
                          f"opcua:\n  enabled: true\n  host: 127.0.0.1\n  port: {port}\n  security: "
                          f"[Basic256Sha256-SignAndEncrypt]\n  users: [{{username: u, password_file: "
                          f"{folder / 'opcua.password'}}}]\n")
    return Case(config, f"opcua.port: 127.0.0.1:{port} is already in use", [])


def password_file_missing(folder: Path) -> Case:
    config = write_config(folder, folder / "state",
                          mqtt_extra=f"  username: gw\n  password_file: {folder / 'no-such-password'}\n")
    return Case(config, f"mqtt.password_file: cannot read {folder / 'no-such-password'}", [])


def password_env_unset(folder: Path) -> Case:
    config = write_config(folder, folder / "state", mqtt_extra="  username: gw\n  password_env: FOCAS_TEST_UNSET\n")
    return Case(config, "mqtt.password_env: environment variable FOCAS_TEST_UNSET is not set", [])


def lock_held(folder: Path, hold: Callable[[Path], None]) -> Case:
    state = folder / "state"
    hold(state)
    return Case(write_config(folder, state), f"state_dir: {state} is in use by another focas-edge (PID {os.getpid()}",
                [])


def config_unreadable(folder: Path) -> Case:
    config = write_config(folder, folder / "state")
    config.chmod(0o600)
    if os.geteuid() == 0:
        return Case(config, f"config: user nobody cannot read {config} (owner root:", as_nobody())
    config.chmod(0o000)
    return Case(config, f"config: user {pwd.getpwuid(os.geteuid()).pw_name} cannot read {config}", [])


@pytest.fixture
def listener() -> Iterator[socket.socket]:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen()
    yield sock
    sock.close()


@pytest.fixture
def hold() -> Iterator[Callable[[Path], None]]:
    """Hold a state_dir's lock in this process, as a running daemon would."""
    held: list[Any] = []

    def take(state: Path) -> None:
        from edge.service.state_lock import StateDirLock

        held.append(StateDirLock.acquire(state))

    yield take
    for lock in held:
        lock.release()


CASES = ["state_dir_unusable", "state_file_of_another_user", "port_taken", "opcua_port_taken", "password_file_missing",
         "password_env_unset", "lock_held", "config_unreadable"]


@pytest.mark.parametrize("name", CASES)
def test_run_refuses_in_one_line_what_check_config_refused_first(
        name: str, open_dir: Path, listener: socket.socket, hold: Callable[[Path], None]) -> None:
    folder = open_dir
    makers: dict[str, Callable[[], Case]] = {
        "state_dir_unusable": lambda: state_dir_unusable(folder),
        "state_file_of_another_user": lambda: state_file_of_another_user(folder),
        "port_taken": lambda: port_taken(folder, listener),
        "opcua_port_taken": lambda: opcua_port_taken(folder, listener),
        "password_file_missing": lambda: password_file_missing(folder),
        "password_env_unset": lambda: password_env_unset(folder),
        "lock_held": lambda: lock_held(folder, hold),
        "config_unreadable": lambda: config_unreadable(folder),
    }
    case = makers[name]()
    env = {k: v for k, v in os.environ.items() if k not in ("STATE_DIRECTORY", "FOCAS_TEST_UNSET")}
    env["PYTHONUNBUFFERED"] = "1"

    def focas_edge(*args: str) -> subprocess.CompletedProcess[str]:
        # a run that is not refused would keep running: the timeout ends it and fails the test
        return subprocess.run([*case.user, *focas_edge_command(), *args], capture_output=True, text=True,
                              timeout=60, env=env, cwd=folder, check=False)

    checked = focas_edge("check-config", str(case.config))
    assert checked.returncode == 2, checked.stdout + checked.stderr
    ran = focas_edge("run", "--config", str(case.config))
    assert ran.returncode == 2, ran.stderr
    assert "Traceback" not in ran.stderr + checked.stderr
    (line,) = ran.stderr.splitlines()  # one line, nothing else
    prefix = f"focas-edge: {case.config}: "
    assert line.startswith(prefix), line
    problem = line.removeprefix(prefix)
    assert problem.startswith(case.expected), problem
    assert f"  {problem}" in checked.stderr.splitlines(), (problem, checked.stderr)


def test_the_fix_in_the_state_file_refusal_works(open_dir: Path) -> None:
    """The line names the command that repairs it; after that command check-config is content."""
    if os.geteuid() != 0:
        pytest.skip("needs root to leave a root-owned file behind")
    case = state_file_of_another_user(open_dir)
    result = subprocess.run([*case.user, *focas_edge_command(), "check-config", str(case.config)],
                            capture_output=True, text=True, timeout=60, check=False)
    fix = result.stderr.rpartition("; fix: ")[2].strip()
    assert fix == f"chown -R nobody:nogroup {open_dir / 'state'}", result.stderr
    subprocess.run(fix.split(), check=True)
    again = subprocess.run([*case.user, *focas_edge_command(), "check-config", str(case.config)],
                           capture_output=True, text=True, timeout=60, check=False)
    assert again.returncode == 0, again.stderr
