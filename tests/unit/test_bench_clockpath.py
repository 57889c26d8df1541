"""bench.clockpath runs end to end at its smallest size, and its digest is a function of behaviour only, so an
A/B of two trees with equal digests means equal clock output."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run() -> str:
    run = subprocess.run(
        [sys.executable, "-m", "bench.clockpath", "--machines", "3", "--seconds", "5", "--warmup", "10"],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    return run.stdout


def test_reports_a_cost_and_a_repeatable_digest() -> None:
    first, second = _run(), _run()
    cost = re.search(r"^([0-9.]+) us a tick, of which send_at ([0-9.]+);", first, re.MULTILINE)
    assert cost is not None, first
    assert float(cost.group(1)) > 0 and float(cost.group(2)) <= float(cost.group(1))
    digests = [re.search(r"^digest ([0-9a-f]{64})$", out, re.MULTILINE) for out in (first, second)]
    assert digests[0] is not None and digests[1] is not None, first + second
    assert digests[0].group(1) == digests[1].group(1)
