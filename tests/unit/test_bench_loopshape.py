"""bench.loopshape runs every loop shape end to end at its smallest size, so the harness never rots."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_shape_answers_requests_and_reports_a_cost() -> None:
    run = subprocess.run(
        [sys.executable, "-m", "bench.loopshape", "--machines", "2", "--pairs", "1", "--duration", "0.5",
         "--warmup", "0.3"],
        cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    for shape in "ACB":
        match = re.search(rf"^shape {shape}: median ([0-9.]+|nan) us/cycle", run.stdout, re.MULTILINE)
        assert match is not None, run.stdout
        assert math.isfinite(float(match.group(1))), f"shape {shape} answered no request:\n{run.stdout}"
