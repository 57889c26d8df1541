"""The day strips kept in state_dir: a restart keeps the day, the time the gateway was down is unknown, a
bad file is ignored with a warning."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from edge.samples import MetricType, Sample
from edge.service.trend_store import TRENDS_FILE, close_trends, load_trends, open_trends, save_trends
from edge.service.trends import Band, TrendRecorder
from tests.unit.service.test_trends import T0, Clock, relative


async def test_a_restart_keeps_the_day_and_the_gap_is_unknown(tmp_path: Path) -> None:
    clock = Clock(T0)
    before = TrendRecorder(clock)
    await before.device_data("m1", [Sample("Status/Run", "START", MetricType.STRING, 0)])
    clock.now = T0 + 600  # ten minutes running, then the daemon stops
    save_trends(before, tmp_path / TRENDS_FILE)
    clock.now = T0 + 900  # five minutes down
    after = TrendRecorder(clock)
    assert load_trends(after, tmp_path / TRENDS_FILE) == 1
    await after.device_data("m1", [Sample("Status/Run", "RESET", MetricType.STRING, 0)])
    clock.now = T0 + 1200
    trend = after.machine("m1")
    assert trend is not None
    assert relative(trend.day.bands(T0 - 60, clock.now)) == [
        (-60, 0, Band.UNKNOWN), (0, 600, Band.RUNNING), (600, 900, Band.UNKNOWN), (900, 1200, Band.IDLE)]


async def test_only_configured_machines_come_back_and_a_bad_file_starts_empty(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock(T0)
    before = TrendRecorder(clock)
    for machine_id in ("m1", "gone"):
        await before.device_data(machine_id, [Sample("Status/Run", "START", MetricType.STRING, 0)])
    close_trends(before, tmp_path)
    document = json.loads((tmp_path / TRENDS_FILE).read_text())
    assert set(document["machines"]) == {"m1", "gone"}
    assert set(open_trends(tmp_path, ["m1", "new"]).machines) == {"m1"}
    document["machines"]["m1"]["slots"] = "AAAA"  # three bytes, not a day
    (tmp_path / TRENDS_FILE).write_text(json.dumps(document))
    with caplog.at_level(logging.WARNING):
        assert set(open_trends(tmp_path, ["m1", "gone"]).machines) == {"gone"}
    assert "machine=m1" in caplog.text and "wrong size" in caplog.text
    (tmp_path / TRENDS_FILE).write_text("{not json")
    with caplog.at_level(logging.WARNING):
        assert open_trends(tmp_path, ["m1"]).machines == {}
    assert "starting empty" in caplog.text
    assert open_trends(tmp_path / "nothing-here", ["m1"]).machines == {}
