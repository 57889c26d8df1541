"""The plant page rendered from a recorder fed by hand: the fleet sorted by trouble, one machine's bands,
utilisation, sparklines and alarms, the routes, and the SVG shapes."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace
from zoneinfo import ZoneInfo

from edge.samples import MetricType, Sample
from edge.service.plant_page import fleet_block, machine_response, render_machine, running_share
from edge.service.svg import duration_text, sparkline_svg, timeline_svg
from edge.service.trends import Band, TrendRecorder

BERLIN = ZoneInfo("Europe/Berlin")
NOON = 1_764_068_400.0  # 2025-11-25 12:00:00 Europe/Berlin (11:00 UTC)


class Clock:
    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def poller(online: bool = True) -> SimpleNamespace:
    return SimpleNamespace(online=online, online_changed_at=NOON - 7200, machine=SimpleNamespace(zone=BERLIN))


def s(name: str, value: object) -> Sample:
    return Sample(name, value, MetricType.STRING, 0)


async def feed(rec: TrendRecorder, clock: Clock, machine_id: str, *steps: tuple[float, list[Sample]]) -> None:
    for at, samples in steps:
        clock.now = at
        await rec.device_data(machine_id, samples)


async def test_the_fleet_is_sorted_by_trouble_then_name_with_a_colour_each() -> None:
    clock = Clock(NOON)
    rec = TrendRecorder(clock)
    await feed(rec, clock, "a-running", (NOON, [s("Status/Run", "START")]))
    await feed(rec, clock, "b-alarm", (NOON, [s("Status/Run", "RESET"), s("Status/Alarm", "ALM")]))
    await feed(rec, clock, "c-emergency", (NOON, [s("Status/Emergency", True)]))
    await feed(rec, clock, "d-idle", (NOON, [s("Status/Execution", "READY")]))
    await feed(rec, clock, "e-hold", (NOON, [s("Status/Execution", "FEED_HOLD")]))
    pollers = {mid: poller() for mid in ("a-running", "b-alarm", "c-emergency", "d-idle", "e-hold")}
    pollers["f-down"] = poller(online=False)  # never seen by the recorder
    page = fleet_block(pollers, rec, NOON + 90)
    rows = re.findall(r'<tr id="fleet-([^"]+)" data-state="([^"]+)"', page)
    assert rows == [("c-emergency", "emergency"), ("b-alarm", "alarm"), ("f-down", "offline"),
                    ("e-hold", "feed-hold"), ("d-idle", "idle"), ("a-running", "running")]
    assert '<span class="dot alarm" title="alarm">' in page and 'href="machine/b-alarm"' in page
    assert "<td>1 min 30 s</td>" in page and "<td>2 h 01 min</td>" in page  # f-down: since its session ended
    assert 'fetch("fleet"' in page and "<script src" not in page and "http" not in page.split("<script>")[1]


async def test_a_machine_page_draws_its_bands_in_order_with_widths_in_proportion() -> None:
    clock = Clock(NOON)
    rec = TrendRecorder(clock)
    await feed(rec, clock, "m1", (NOON - 1800, [s("Status/Run", "START"), s("Status/Alarm", "")]),
               (NOON - 1200, [s("Status/Run", "HOLD")]), (NOON - 900, [s("Status/Alarm", "ALM")]))
    clock.now = NOON - 600
    await rec.device_offline("m1")
    page = render_machine("m1", poller(online=False), rec.machine("m1"), NOON)
    hour = re.search(r'<svg id="timeline-hour".*?</svg>', page, re.S)
    assert hour is not None
    bands = re.findall(r'<rect class="band ([a-z-]+)" x="([\d.]+)" y="0" width="([\d.]+)"', hour.group(0))
    assert [(css, round(float(w))) for css, _, w in bands] == [
        ("unknown", 500), ("running", 167), ("feed-hold", 83), ("alarm", 83), ("offline", 167)]
    assert float(bands[1][1]) == 500.0  # starts half an hour in
    day = re.search(r'<svg id="timeline-day".*?</svg>', page, re.S)
    assert day is not None
    day_bands = re.findall(r'<rect class="band ([a-z-]+)"', day.group(0))
    assert day_bands == ["unknown", "running", "feed-hold", "alarm", "offline"]
    assert re.search(r">21:00</text>", day.group(0)) and re.search(r">11:20</text>", hour.group(0))
    assert 'id="state">offline</strong>' in page and '<meta http-equiv="refresh" content="10">' in page


async def test_utilisation_uses_the_published_seconds_and_else_what_was_recorded_today() -> None:
    clock = Clock(NOON)
    rec = TrendRecorder(clock)
    midnight = NOON - 12 * 3600
    await feed(rec, clock, "m1", (midnight + 6 * 3600, [s("Status/Run", "START")]))
    clock.now = NOON
    trend = rec.machine("m1")
    assert trend is not None
    share = running_share(trend, NOON, BERLIN)
    assert share is not None and abs(share - 0.5) < 0.01  # 6 h running of 12 h since midnight
    await rec.device_data("m1", [Sample("Utilisation/ACTIVE", 3600.0, MetricType.DOUBLE, 0),
                                 Sample("Utilisation/READY", 10_800.0, MetricType.DOUBLE, 0),
                                 s("Utilisation/Day", "2025-11-25")])
    assert running_share(trend, NOON, BERLIN) == 0.25
    assert 'id="utilisation">25 %</strong>' in render_machine("m1", poller(), trend, NOON)


async def test_sparklines_and_the_alarms_of_today_only() -> None:
    clock = Clock(NOON - 600)
    rec = TrendRecorder(clock)
    await rec.device_data("m1", [Sample("Spindle/1/Load", 42.0, MetricType.DOUBLE, 0),
                                 Sample("Feed/Actual", 1200.0, MetricType.DOUBLE, 0)])
    for at, number, message in ((NOON - 13 * 3600, 1, "YESTERDAY"), (NOON - 60, 1004, "COOLANT <LOW>")):
        event = {"event": "raised", "type": 2, "number": number, "axis": 0, "message": message,
                 "timestamp_ms": int(at * 1000)}
        await rec.device_events("m1", [s("Alarm/Event", json.dumps(event))])
    page = render_machine("m1", poller(), rec.machine("m1"), NOON)
    assert "COOLANT &lt;LOW&gt;" in page and "YESTERDAY" not in page and "<td>11:59:00</td>" in page
    assert re.search(r'<svg id="spark-Spindle-1-Load" class="spark".*?<polyline class="mean" points="[^"]+"', page)
    assert "0 .. 42" in page and "0 .. 1200" in page


async def test_routes_an_unknown_machine_and_an_id_that_needs_escaping() -> None:
    clock = Clock(NOON)
    rec = TrendRecorder(clock)
    await rec.device_data("<m&1>", [s("Status/Run", "START")])
    pollers = {"<m&1>": poller()}
    status, body = machine_response("/machine/%3Cm%261%3E", pollers, rec)
    assert status == 200 and "<h1>&lt;m&amp;1&gt;</h1>" in body and "<m&1>" not in body
    status, body = machine_response("/machine/nope", pollers, rec)
    assert status == 404 and "no machine 'nope'" in body and "&lt;m&amp;1&gt;" in body
    status, body = machine_response("/fleet", pollers, rec)
    assert status == 200 and body.startswith('<section id="fleet">') and 'href="machine/%3Cm%261%3E"' in body


def test_timeline_clips_to_its_window_and_a_sparkline_breaks_at_gaps() -> None:
    svg = timeline_svg("t", [(0.0, 50.0, Band.IDLE), (50.0, 150.0, Band.RUNNING)], 25.0, 125.0, [],
                       lambda t: str(t))
    assert re.findall(r'class="band (\w+)" x="([\d.]+)" y="0" width="([\d.]+)"', svg) == [
        ("idle", "0.000", "250.000"), ("running", "250.000", "750.000")]
    line, low, high = sparkline_svg("sp", [1.0, 2.0, None, 4.0, None, 3.0, 3.5], [1.0, 5.0] + [None] * 5)
    assert (low, high) == (0.0, 5.0) and line.count('<polyline class="mean"') == 2
    assert line.count('<circle class="mean"') == 1 and line.count('<polyline class="peak"') == 1
    assert sparkline_svg("sp", [None, None])[1:] == (None, None)
    assert (duration_text(12), duration_text(270), duration_text(3900)) == ("12 s", "4 min 30 s", "1 h 05 min")


async def test_the_recent_timeline_zooms_to_a_few_minutes_and_a_bad_width_is_refused() -> None:
    clock = Clock(NOON - 90)
    rec = TrendRecorder(clock)
    await feed(rec, clock, "m1", (NOON - 90, [s("Status/Run", "START")]), (NOON - 30, [s("Status/Run", "HOLD")]))
    pollers = {"m1": poller()}
    clock.now = NOON
    status, page = machine_response("/machine/m1?minutes=2", pollers, rec)
    hour = re.search(r'<svg id="timeline-hour".*?</svg>', page, re.S)
    assert status == 200 and hour is not None and "Last 2 minutes" in page
    widths = [round(float(w)) for w in re.findall(r'class="band [a-z-]+" x="[\d.]+" y="0" width="([\d.]+)"',
                                                   hour.group(0))]
    assert widths == [250, 500, 250]  # 30 s unknown, 60 s running, 30 s held, of 120 s
    assert "Spindle load and feed rate, last 2 minutes" in page and 'href="?minutes=60"' in page
    assert 'id="utilisation">0.1 %</strong>' in page  # 60 s of the 11 h since midnight, not "0 %"
    for bad in ("0", "61", "x", "-5"):
        status, page = machine_response(f"/machine/m1?minutes={bad}", pollers, rec)
        assert status == 400 and "expected a whole number of minutes from 1 to 60" in page
