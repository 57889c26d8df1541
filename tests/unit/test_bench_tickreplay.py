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


def test_the_cost_model_recovers_the_costs_a_tick_was_built_from() -> None:
    # ticks that vary in each feature, their time an exact sum: the fit gives the parts back
    rows = [tickreplay.tick_features(groups, samples, moved, news)
            for groups in (set(), {tickreplay.pl.Group.LOADS}, {tickreplay.pl.Group.COUNTERS})
            for samples in (3, 9, 17) for moved in (2, 5) for news in (False, True)]
    truth = [30.0, 1.5, 2.0, 4.0, 12.0, 8.0]
    times = [sum(c * x for c, x in zip(truth, row, strict=True)) for row in rows]
    fitted = tickreplay.fit_cost_model(rows, times)
    assert list(fitted) == list(tickreplay.FEATURES)
    assert [round(fitted[name], 6) for name in tickreplay.FEATURES] == truth


def test_a_replay_timed_per_tick_describes_every_replayed_tick() -> None:
    recording = asyncio.run(tickreplay._record(0.1, 1.5))
    ticks = asyncio.run(tickreplay._replay(recording, 2, 1, "default", per_tick=True))
    assert len(ticks["rows"]) == len(ticks["us"]) == 2 * len(recording["ticks"])
    assert all(row[0] == 1.0 and row[1] >= 0 and row[2] >= 1 for row in ticks["rows"])  # the stamp macro moves


def test_the_cost_model_gives_features_that_move_together_one_coefficient() -> None:
    # a short recording: servo loads, counters and the clock's second read on the same ticks only
    rows = [[1.0, float(samples), float(moved), flag, flag, flag]
            for samples in (3, 9, 17) for moved in (2, 5) for flag in (0.0, 1.0)]
    times = [30.0 + 1.5 * r[1] + 2.0 * r[2] + 24.0 * r[3] for r in rows]
    fitted = tickreplay.fit_cost_model(rows, times)
    assert list(fitted) == ["fixed", "published value", "moved read", "servo loads read"]
    assert [round(v, 6) for v in fitted.values()] == [30.0, 1.5, 2.0, 24.0]
