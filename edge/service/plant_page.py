"""The plant's view on the status endpoint: the fleet at a glance, and one page per machine.

The fleet overview (a section at the top of `/`, re-fetched from `/fleet` every few seconds by a few lines
of plain script) has one row per machine, its state as a colour, sorted by trouble: emergency, alarm,
offline first. It stays cheap at 1,000 machines: no timeline per row, only counts. `/machine/<id>` draws
the last 24 h and the last hour as coloured bands, today's utilisation, spindle load and feed rate over
the last hour, and today's alarms; it reloads itself (meta refresh, no script needed).

Everything comes from the TrendRecorder (edge.service.trends) and the pollers, read on the event loop.
"""

from __future__ import annotations

import html
import time
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime, tzinfo
from typing import Any
from urllib.parse import parse_qs, quote, unquote

from edge.service.svg import duration_text, sparkline_svg, timeline_svg
from edge.service.trends import (
    HOUR_S,
    SPARK_SERIES,
    SPARK_STEP_S,
    TROUBLE,
    TROUBLE_RANK,
    Band,
    MachineTrend,
    TrendRecorder,
)

FLEET_REFRESH_MS = 5000
TROUBLE_CLASS = ' class="trouble"'
MACHINE_REFRESH_S = 10
RECENT_MINUTES = 60  # the recent timeline: the last hour, or fewer minutes (?minutes=N) to zoom in
DAY_S = 24 * HOUR_S
EXECUTION_RUNNING = "ACTIVE"  # the Utilisation/<STATE> that counts as running

STYLE = """
.band.running,.dot.running{fill:#2e7d32;background:#2e7d32}
.band.idle,.dot.idle{fill:#f2c94c;background:#f2c94c}
.band.feed-hold,.dot.feed-hold{fill:#f2994a;background:#f2994a}
.band.alarm,.dot.alarm{fill:#d32f2f;background:#d32f2f}
.band.emergency,.dot.emergency{fill:#7b1fa2;background:#7b1fa2}
.band.offline,.dot.offline{fill:#616161;background:#616161}
.band.unknown,.dot.unknown{fill:#d9d9d9;background:#d9d9d9}
.dot{display:inline-block;width:1em;height:1em;border-radius:50%;vertical-align:middle}
#fleet table{margin-bottom:1.2em;width:auto;min-width:40em}#fleet h2{font-size:1.1em}
#fleet tr.trouble td{background:#fff3f3}
svg.timeline{display:block;margin:.2em 0 .8em;background:#fff;border:1px solid #ddd}
svg.timeline text{font:10px system-ui,sans-serif;fill:#555}svg.timeline line.tick{stroke:#888}
svg.spark{background:#fff;border:1px solid #ddd}svg.spark polyline{fill:none;stroke-width:1.5}
svg.spark .mean{stroke:#1565c0}svg.spark circle.mean{fill:#1565c0}svg.spark .peak{stroke:#b0c4de}
svg.spark circle.peak{fill:#b0c4de}.legend>span{margin-right:1em}.sparks{display:flex;gap:2em;flex-wrap:wrap}
"""


@dataclass(frozen=True, slots=True)
class FleetRow:
    machine_id: str
    band: Band
    since: float
    running_share: float | None  # of today so far, 0..1


def zone_of(poller: Any) -> tzinfo:
    zone = getattr(getattr(poller, "machine", None), "zone", None)
    return zone if isinstance(zone, tzinfo) else UTC


def local_midnight(now: float, zone: tzinfo) -> float:
    today = datetime.fromtimestamp(now, zone)
    return today.replace(hour=0, minute=0, second=0, microsecond=0).timestamp()


def current_band(poller: Any, trend: MachineTrend | None) -> Band:
    """The recorder's band; a poller without a CNC session is offline whatever was recorded last."""
    if poller is not None and not poller.online:
        return Band.OFFLINE
    return trend.band if trend is not None else Band.UNKNOWN


def band_since(poller: Any, trend: MachineTrend | None, band: Band, now: float) -> float:
    """Since when the machine is in `band`: the recorder's, or the poller's session change for an offline
    machine the recorder never saw."""
    if trend is not None and trend.band is band:
        return trend.since
    return float(getattr(poller, "online_changed_at", now))


def running_share(trend: MachineTrend | None, now: float, zone: tzinfo) -> float | None:
    """Today's share of running time: from the published Utilisation/<STATE> seconds when the collector
    sends them (they survive restarts), else from what this process recorded since local midnight."""
    if trend is None:
        return None
    published = {k: v for k, v in trend.utilisation.items() if isinstance(v, int | float) and k != "Day"}
    if published and EXECUTION_RUNNING in published:
        total = sum(published.values())
        return published[EXECUTION_RUNNING] / total if total > 0 else None
    midnight = local_midnight(now, zone)
    elapsed = now - midnight
    return trend.day.seconds_in(Band.RUNNING, midnight, now) / elapsed if elapsed > 0 else None


def fleet_rows(pollers: Mapping[str, Any], trends: TrendRecorder, now: float) -> list[FleetRow]:
    rows = []
    for machine_id, poller in pollers.items():
        trend = trends.machine(machine_id)
        band = current_band(poller, trend)
        rows.append(FleetRow(machine_id, band, band_since(poller, trend, band, now),
                             running_share(trend, now, zone_of(poller))))
    rows.sort(key=lambda row: (TROUBLE_RANK[row.band], row.machine_id))
    return rows


def _share_text(share: float | None) -> str:
    """Whole percent; a tenth below 10 % (early in the day 0.3 % is not 0 %)."""
    if share is None:
        return "-"
    percent = share * 100
    return f"{percent:.1f} %" if percent < 10 else f"{percent:.0f} %"


def render_fleet(pollers: Mapping[str, Any], trends: TrendRecorder, now: float | None = None) -> str:
    """The fleet section (also served alone at /fleet, which the section's script re-fetches)."""
    now = time.time() if now is None else now
    rows = fleet_rows(pollers, trends, now)
    counts = {band: 0 for band in TROUBLE}
    for row in rows:
        counts[row.band] += 1
    summary = " · ".join(f'<span class="dot {band.css}"></span> {counts[band]} {band.label}'
                         for band in TROUBLE if counts[band])
    body = "".join(
        f'<tr id="fleet-{html.escape(row.machine_id)}" data-state="{row.band.css}"'
        f'{TROUBLE_CLASS if TROUBLE_RANK[row.band] < TROUBLE_RANK[Band.FEED_HOLD] else ""}>'
        f'<td><span class="dot {row.band.css}" title="{row.band.label}"></span></td>'
        f'<td><a href="machine/{quote(row.machine_id, safe="")}">{html.escape(row.machine_id)}</a></td>'
        f"<td>{row.band.label}</td><td>{duration_text(now - row.since)}</td>"
        f"<td>{_share_text(row.running_share)}</td></tr>"
        for row in rows)
    return (f'<section id="fleet"><h2>Fleet</h2><p class="legend">{summary or "no machines"}</p>'
            "<table><thead><tr><th></th><th>machine</th><th>state</th><th>for</th><th>running today</th></tr>"
            f"</thead><tbody>{body}</tbody></table></section>")


FLEET_SCRIPT = f"""<script>
setInterval(async () => {{
  try {{ const r = await fetch("fleet", {{cache: "no-store"}});
    if (r.ok) document.getElementById("fleet").outerHTML = await r.text(); }} catch (e) {{}}
}}, {FLEET_REFRESH_MS});
</script>"""


def fleet_block(pollers: Mapping[str, Any], trends: TrendRecorder, now: float | None = None) -> str:
    """What `/` shows on top: the styles, the fleet section and its refresh script."""
    now = trends.clock() if now is None else now
    return f"<style>{STYLE}</style>{render_fleet(pollers, trends, now)}{FLEET_SCRIPT}"


# ---- one machine --------------------------------------------------------------------------------------------


def _clock(zone: tzinfo, with_seconds: bool = True) -> Any:
    fmt = "%H:%M:%S" if with_seconds else "%H:%M"
    return lambda t: datetime.fromtimestamp(t, zone).strftime(fmt)


def _ticks(start: float, end: float, every_s: float, zone: tzinfo) -> list[tuple[float, str]]:
    """Tick marks on local round times (every 3 h, every 10 min), labelled HH:MM."""
    offset = datetime.fromtimestamp(start, zone).utcoffset()
    shift = offset.total_seconds() if offset is not None else 0.0
    first = ((start + shift) // every_s + 1) * every_s - shift
    label = _clock(zone, with_seconds=every_s < 60)
    ticks, at = [], first
    while at < end:
        ticks.append((at, label(at)))
        at += every_s
    return ticks


def _tick_step(span_s: float) -> float:
    """About six ticks on round local times."""
    return next((step for step in (10, 30, 60, 120, 300, 600) if span_s / step <= 7), 600)


def _recent_title(minutes: int) -> str:
    return "Last hour" if minutes == 60 else f"Last {minutes} minute{'s' if minutes > 1 else ''}"


def _legend() -> str:
    return '<p class="legend">' + "".join(f'<span><span class="dot {band.css}"></span> {band.label}</span>'
                                          for band in TROUBLE) + "</p>"


def _sparks(trend: MachineTrend, now: float, minutes: int) -> str:
    """The sparklines over the same span as the recent timeline (the last hour, or the zoom)."""
    cells = []
    for name, label in SPARK_SERIES.items():
        means, peaks = trend.sparks[name].series(now, max(2, round(minutes * 60 / SPARK_STEP_S)))
        svg, low, high = sparkline_svg(f"spark-{name.replace('/', '-')}", means, peaks)
        scale = "no value in this span" if high is None else f"{low:g} .. {high:g}"
        cells.append(f"<div><strong>{html.escape(label)}</strong> <small>({html.escape(name)}; mean and, faint, "
                     f"peak per {SPARK_STEP_S:g} s; {scale})</small><br>{svg}</div>")
    return '<div class="sparks">' + "".join(cells) + "</div>"


def _alarms(trend: MachineTrend, midnight: float, zone: tzinfo) -> str:
    today = [note for note in trend.alarms if note.at >= midnight]
    if not today:
        return '<p id="alarms" class="muted">no alarm raised or cleared today (since this process started)</p>'
    clock = _clock(zone)
    rows = "".join(f"<tr><td>{clock(n.at)}</td><td>{html.escape(n.event)}</td><td>{n.number}</td>"
                   f"<td>{html.escape(str(n.type))}</td><td>{html.escape(n.message)}</td></tr>"
                   for n in reversed(today))
    return ('<table id="alarms"><thead><tr><th>time</th><th>event</th><th>number</th><th>type</th><th>message</th>'
            f"</tr></thead><tbody>{rows}</tbody></table>")


def render_machine(machine_id: str, poller: Any, trend: MachineTrend | None, now: float | None = None,
                   recent_minutes: int = RECENT_MINUTES) -> str:
    """The whole page of one machine (it reloads itself); the recent timeline spans `recent_minutes`."""
    now = time.time() if now is None else now
    recent_s = recent_minutes * 60.0
    zone = zone_of(poller)
    band = current_band(poller, trend)
    e = html.escape
    if trend is None:
        content = "<p>nothing recorded for this machine yet</p>"
    else:
        midnight = local_midnight(now, zone)
        since = band_since(poller, trend, band, now)
        day = timeline_svg("timeline-day", trend.day.bands(now - DAY_S, now), now - DAY_S, now,
                           _ticks(now - DAY_S, now, 3 * HOUR_S, zone), _clock(zone, with_seconds=False))
        hour = timeline_svg("timeline-hour", trend.hour.bands(now - recent_s, now), now - recent_s, now,
                            _ticks(now - recent_s, now, _tick_step(recent_s), zone), _clock(zone))
        zoom = "" if recent_minutes == RECENT_MINUTES else ' (<a href="?minutes=60">last hour</a>)'
        content = (f'<p><span class="dot {band.css}"></span> <strong id="state">{band.label}</strong> for '
                   f"{duration_text(now - since)} · running today: "
                   f'<strong id="utilisation">{_share_text(running_share(trend, now, zone))}</strong></p>'
                   f"{_legend()}<h2>Last 24 hours</h2>{day}<h2>{_recent_title(recent_minutes)}{zoom}</h2>{hour}"
                   f"<h2>Spindle load and feed rate, {_recent_title(recent_minutes).lower()}</h2>"
                   f"{_sparks(trend, now, recent_minutes)}"
                   f"<h2>Alarms today</h2>{_alarms(trend, midnight, zone)}")
    generated = datetime.fromtimestamp(now, zone).isoformat(timespec="seconds")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{e(machine_id)} · focas-edge</title>
<meta http-equiv="refresh" content="{MACHINE_REFRESH_S}">
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>body{{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222;background:#fafafa}}
h1{{font-size:1.3em;margin:0 0 .3em}}h2{{font-size:1.05em;margin:1em 0 .2em}}.muted{{color:#777}}
table{{border-collapse:collapse;background:#fff}}th,td{{border:1px solid #ddd;padding:.3em .5em;text-align:left}}
{STYLE}</style></head>
<body data-machine="{e(machine_id)}" data-state="{band.css}">
<p><a href="../">&larr; all machines</a></p>
<h1>{e(machine_id)}</h1>
<small>rendered {e(generated)} (machine time zone); reloads every {MACHINE_REFRESH_S} s</small>
{content}
</body></html>
"""


def machine_response(path: str, pollers: Mapping[str, Any], trends: TrendRecorder) -> tuple[int, str]:
    """(HTTP status, HTML) for /fleet and /machine/<id>[?minutes=N]; an unknown machine is a 404 naming the
    known ones, a bad `minutes` a 400 saying what is allowed."""
    route, _, query = path.partition("?")
    now = trends.clock()  # the recorder's clock: the bands' and the page's times agree
    if route == "/fleet":
        return 200, render_fleet(pollers, trends, now)
    machine_id = unquote(route.removeprefix("/machine/"))
    poller = pollers.get(machine_id)
    if poller is None:
        known = ", ".join(sorted(pollers)[:20]) or "none"
        return 404, (f"<!doctype html><title>no such machine</title><p>no machine {html.escape(machine_id)!r}; "
                     f"known: {html.escape(known)}{' ...' if len(pollers) > 20 else ''}</p>")
    minutes = parse_qs(query).get("minutes", [str(RECENT_MINUTES)])[-1]
    if not minutes.isdigit() or not 1 <= int(minutes) <= RECENT_MINUTES:
        return 400, (f"<!doctype html><title>bad request</title><p>minutes={html.escape(minutes)!r}: expected a "
                     f"whole number of minutes from 1 to {RECENT_MINUTES} (the recent timeline's width)</p>")
    return 200, render_machine(machine_id, poller, trends.machine(machine_id), now, int(minutes))
