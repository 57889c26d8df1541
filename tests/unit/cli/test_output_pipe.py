"""A command whose reader goes away (`focas-edge check-config FILE | head -1`) ends quietly: edge.cli's main
handles BrokenPipeError once for every subcommand, instead of two tracebacks (one from the write, one from
the interpreter's flush at exit)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def test_a_reader_that_goes_away_ends_a_long_listing_quietly(tmp_path: Path) -> None:
    """`focas-edge check-config FILE | head -1`: no BrokenPipeError traceback (stdout's reader is gone)."""
    machines = "".join(f"  - {{id: m{i}, host: 10.0.{i // 250}.{i % 250 + 1}}}\n" for i in range(400))
    config = tmp_path / "big.yaml"
    config.write_text(f"mqtt: {{host: localhost, formats: [json]}}\nstate_dir: {tmp_path / 'state'}\n"
                      f"machines:\n{machines}")
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader has gone before the first write: every write meets EPIPE
    try:
        result = subprocess.run([sys.executable, "-m", "edge", "check-config", str(config)], stdout=write_end,
                                stderr=subprocess.PIPE, text=True, timeout=60, check=False)
    finally:
        os.close(write_end)
    assert "Traceback" not in result.stderr and "BrokenPipe" not in result.stderr, result.stderr
    assert result.returncode == 141  # as a shell reports a command ended by SIGPIPE

