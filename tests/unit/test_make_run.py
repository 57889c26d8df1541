"""`make run` installs only what running needs and writes nothing into tracked files."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def dry_run(target: str, tmp_path: Path, *variables: str) -> str:
    """The commands `make` would run for `target` with a venv that does not exist yet."""
    if shutil.which("make") is None:
        pytest.skip("no make")
    done = subprocess.run(["make", "-n", "-C", str(REPO), target, f"VENV={tmp_path / 'venv'}", *variables],
                          capture_output=True, text=True, timeout=30, check=True)
    return done.stdout


def test_make_run_installs_the_package_the_demo_broker_and_the_opcua_extra_only(tmp_path: Path) -> None:
    commands = dry_run("run", tmp_path)
    installs = [line for line in commands.splitlines() if "pip install" in line]
    assert installs == [f"{tmp_path / 'venv'}/bin/python -m pip install --quiet -e '.[demo,opcua]'"], commands
    assert "-m edge.cli.views.demo" in commands and "--raw" not in commands


def test_make_run_raw_is_one_variable_away(tmp_path: Path) -> None:
    assert "-m edge.cli.views.demo --raw" in dry_run("run", tmp_path, "RAW=1")
    assert "-m edge.cli.views.demo  --raw" in dry_run("run", tmp_path, "ARGS=--raw")


def test_make_test_still_installs_everything_and_sets_up_broker_and_browser(tmp_path: Path) -> None:
    commands = dry_run("test", tmp_path)
    assert "-e '.[test,dev,demo,bench,opcua]'" in commands
    assert "scripts/ensure-mosquitto.sh" in commands and "scripts/ensure-chromium.sh" in commands
    assert "scripts/ensure-node-opcua.sh" in commands


def test_the_demo_state_directory_is_not_tracked() -> None:
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    tracked = subprocess.run(["git", "-C", str(REPO), "ls-files", ".state"], capture_output=True, text=True,
                             check=True).stdout
    assert tracked == ""
    ignored = subprocess.run(["git", "-C", str(REPO), "check-ignore", "-q", ".state/sparkplug_bdseq.json"])
    assert ignored.returncode == 0
