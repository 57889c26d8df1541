"""Every benchmark runs end to end at its smallest size, so the harness never rots (no speed assertions)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import pytest

from bench import codec, fleet, floor, outage, plant_page, reload, roundtrip, writes
from bench.__main__ import main
from bench.report import percentile
from bench.simproc import stamp_latency, stamp_value
from bench.timing import Rate, measure_rate
from tests.helpers import mosquitto_binary

needs_broker = pytest.mark.skipif(mosquitto_binary() is None, reason="mosquitto is not installed")


def _one_shot(call: Callable[[], object], units_per_call: int, seconds: float = 1.0, repeats: int = 5) -> Rate:
    return measure_rate(call, units_per_call, seconds=0.001, repeats=1)


def test_stamp_latency_survives_the_modulo_wrap() -> None:
    assert stamp_latency(stamp_value(1_700_000_999.990), 1_700_001_000.040) == pytest.approx(0.05, abs=1e-3)
    assert percentile([3.0, 1.0, 2.0], 50) == 2.0 and math.isnan(percentile([], 99))


def test_codec_rows_cover_every_codec(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(codec, "measure_rate", _one_shot)
    result = codec.run(quick=True)
    cases = " ".join(row["case"] for row in result.rows)
    for word in ("frame decode", "frame build", "response decode", "8-byte", "ODBALMHIS", "Sparkplug",
                 "change detection"):
        assert word in cases
    assert all(row["best/s"] > 0 for row in result.rows)


def test_roundtrip_batches_one_pdu_and_compares_three_clients() -> None:
    result = roundtrip.run(quick=True, ks=[1, 4], cycles=2, latency_s=0.001)
    _, k4 = result.rows
    assert k4["PDUs"] == 1 and k4["per_item_ms"] > k4["batched_ms"]
    assert k4["pyfocas_ms"] is not None
    assert k4["batched/RTT"] > 0 and k4["per_item/batched"] > 1  # the ratios the issue asks to print


@needs_broker
def test_fleet_measures_cpu_cycles_and_latency() -> None:
    row = fleet.run_fleet(fleet.FleetOptions(2, duration_s=2.0, warmup_s=0.2))
    assert row["cycles_per_s"] > 0 and row["rss_mb"] > 0
    assert row["cpu_us_per_cycle"] > 0 and not math.isnan(row["sample_p50_ms"])
    assert row["achieved_pct"] > 0 and row["planned_per_s"] == 20 and row["overruns"] >= 0
    assert row["changes_seen"] > 0 and not math.isnan(row["change_p99_ms"])  # a simulator change reached a subscriber


@needs_broker
def test_reload_measures_births_and_a_machine_added_without_disturbing_the_others() -> None:
    row = reload.run_reload(3, period_s=0.5, watch_s=1.5)
    assert 0 < row["all_born_s"] < 60 and 0 < row["added_born_s"] < 20
    assert (row["other_dbirths"], row["ddeaths"], row["seq_gaps"], row["silent_machines"]) == (0, 0, 0, 0)


@needs_broker
def test_outage_counts_losses_replay_and_descriptors(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(outage, "WARMUP_S", 2.0)
    first, row = outage.run_outage(2, period_s=0.5, outage_s=3.0, after_s=1.0, outages=2)
    assert row["lost"] == 0 and row["collected"] > 0 and row["daemon_exit"] == 0
    assert all(r["spooled_rows"] > 0 and r["backlog_values"] > 0 and r["fds_after"] > 0 for r in (first, row))


def test_floor_measures_each_level_against_the_fleet_simulators() -> None:
    result = floor.run(quick=True, machines=2, duration_s=0.5)
    assert [row["level"] for row in result.rows] == ["round trip", "client batch", "poller"]
    assert all(row["cpu_us_per_cycle"] > 0 and row["achieved_pct"] > 0 for row in result.rows)


@needs_broker
def test_writes_reports_latency_for_both_transports() -> None:
    result = writes.run(quick=True, writes=2)
    assert result.status == "ok", result.notes
    assert {row["transport"] for row in result.rows} == {"focas", "packed"}
    assert all(row["failed"] == 0 and row["p99_ms"] >= row["p50_ms"] > 0 for row in result.rows)


def test_plant_page_renders_a_fleet_with_a_day_of_history() -> None:
    result = plant_page.run(sizes=[3])
    (row,) = result.rows
    assert row["machines"] == 3 and row["fleet_render_ms_median"] > 0 and row["machine_page_ms_median"] > 0
    assert row["kb_per_machine"] > 0 and row["record_us_per_batch"] > 0 and len(result.checks) == 2


def test_cli_saves_json(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(codec, "measure_rate", _one_shot)
    assert main(["codec", "--quick", "--results", str(tmp_path)]) == 0
    saved = json.loads((tmp_path / "codec.json").read_text())
    assert saved["machine"]["cores"] and saved["rows"] and saved["checks"]
