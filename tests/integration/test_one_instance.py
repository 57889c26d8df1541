"""One daemon per state_dir: a second `focas-edge run` on the same state_dir (a cloned config) exits 2 with
one line naming the state_dir and the PID that holds it, check-config says the same, and kill -9 of the
holder frees the state_dir for the next daemon (the kernel drops the flock)."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from edge.cli import main
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.test_signals import DaemonProcess, daemon_config

pytestmark = pytest.mark.integration


def started(daemon: DaemonProcess) -> bool:
    return "started version=" in daemon.output()


async def test_a_second_daemon_on_one_state_dir_is_refused_until_the_first_is_gone(
        mosquitto: Mosquitto, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    state = tmp_path / "state"
    daemons: list[DaemonProcess] = []
    try:
        async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
            text = daemon_config(mosquitto, state, {"m1": fleet[0].port})
            first_config, clone = tmp_path / "first.yaml", tmp_path / "clone.yaml"
            first_config.write_text(text)
            clone.write_text(text)  # the second gateway, cloned from the first
            first = DaemonProcess(first_config)
            daemons.append(first)
            await first.start()
            await async_wait_for(lambda: started(first), 30, message="the first daemon started")

            second = DaemonProcess(clone)
            daemons.append(second)
            await second.start()
            assert await second.wait(30) == 2, second.output()
            (line,) = second.output().splitlines()
            assert line.startswith(f"focas-edge: {clone}: state_dir: {state} is in use by another focas-edge "
                                   f"(PID {first.pid}"), line
            assert not started(second)

            capsys.readouterr()
            assert main(["check-config", str(clone)]) == 2
            assert f"  {line.removeprefix(f'focas-edge: {clone}: ')}" in capsys.readouterr().err.splitlines()

            first.signal(signal.SIGKILL)  # no clean stop: only the kernel can let go of the lock
            assert await first.wait(10) == -signal.SIGKILL

            third = DaemonProcess(clone)
            daemons.append(third)
            await third.start()
            await async_wait_for(lambda: started(third), 30, message="a daemon starts once the holder is gone")
            assert (state / "focas-edge.lock").read_text().strip() == str(third.pid)
            third.signal(signal.SIGTERM)
            assert await third.wait(20) == 0, third.output()
    finally:
        for daemon in daemons:
            await daemon.kill()
