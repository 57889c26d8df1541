"""The in-process OPC UA counters (bench.opcua_idle, bench.opcua_notify) run end to end at their smallest size,
so the harness the OPC UA cost figures come from never rots."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("asyncua", reason="the opcua extra is not installed")

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> str:
    run = subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         check=False)
    assert run.returncode == 0, run.stderr
    return run.stdout


def test_idle_counts_the_hand_over_of_every_batch() -> None:
    out = _run("bench.opcua_idle", "--machines", "2", "--metrics", "5", "--ticks", "5", "--rounds", "1")
    report = ast.literal_eval(out.strip().splitlines()[-1])
    assert report["machines"] == 2
    assert report["failures"] == 0 and report["dropped"] == 0
    assert report["us_per_batch_with_server"][0] > 0 and report["us_per_batch_without"][0] > 0


def test_notify_reports_a_cost_per_notification() -> None:
    out = _run("bench.opcua_notify", "--machines", "2", "--metrics", "5", "--ticks", "5")
    report = ast.literal_eval(out.strip().splitlines()[-1])
    assert report["monitored_items"] == 10
    assert report["notifications"] > 0 and report["publish_responses"] > 0, report
    assert report["cpu_us_per_notification"] > 0 and report["bytes_per_notification"] > 0
