"""bench.tickreplay records one simulated CNC and replays it to several pollers (no speed assertions)."""

from __future__ import annotations

import asyncio
import re

import pytest

from bench import tickreplay


def test_a_recording_replays_to_every_machine_with_the_same_samples(capsys: pytest.CaptureFixture[str]) -> None:
    recording = asyncio.run(tickreplay._record(0.1, 1.5))
    assert len(recording["ticks"]) >= 5 and recording["sysinfo"] is not None
    asyncio.run(tickreplay._replay(recording, 3, 1, "default"))
    line = capsys.readouterr().out.strip().splitlines()[-1]
    match = re.search(r"3 machines, (\d+) ticks, ([\d.]+) samples/tick", line)
    assert match is not None, line
    assert int(match[1]) == 3 * len(recording["ticks"])
    assert float(match[2]) > 0  # the stamp and clock macros move every tick
