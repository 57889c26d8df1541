"""The status page at `/` of the status endpoint, and the `/status.json` document it polls.

For the person standing at the gateway: per machine, connected or not and since when, the series, the
poll rate achieved against the rate planned, the last error, the functions the control refused, the
active alarms and a few live values; for the gateway, the broker session, the spool depth, whether
writes are on, and the version. The page is rendered on the server (it is useful without JavaScript)
and a small inline script re-reads `/status.json` every second and redraws it. No build step, no
external files: the endpoint binds to localhost by default and a gateway often has no internet.

Everything is read on the daemon's event loop (as /metrics is), so no locks are needed.
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from edge import __version__
from edge.service.daemon_view import DaemonView, spool_depth

LIVE_VALUE_PREFIXES = ("Status/Run", "Status/Mode", "Program/Number", "Spindle/1/Speed", "Feed/Actual",
                       "Counters/Parts")
REFRESH_MS = 1000


def _iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, UTC).isoformat(timespec="seconds")


def value_text(value: object) -> str:
    """A value for people: empty shows as (none), floats without trailing zeros."""
    if value is None or value == "":
        return "(none)"
    if isinstance(value, float):
        return f"{value:.3f}".rstrip("0").rstrip(".")
    return str(value)


class RateMeter:
    """Status reads per second per machine, measured between two reads of the document (at least 0.5 s
    apart); None until there are two."""

    MIN_WINDOW_S = 0.5

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, int]] = {}
        self._rate: dict[str, float] = {}

    def rate(self, machine_id: str, ticks: int, now: float) -> float | None:
        previous = self._last.get(machine_id)
        if previous is None or ticks < previous[1]:
            self._last[machine_id] = (now, ticks)
        elif now - previous[0] >= self.MIN_WINDOW_S:
            self._rate[machine_id] = (ticks - previous[1]) / (now - previous[0])
            self._last[machine_id] = (now, ticks)
        return self._rate.get(machine_id)


def _machine(machine_id: str, poller: Any, meter: RateMeter, now: float) -> dict[str, Any]:
    sysinfo = getattr(poller.session, "sysinfo", None)
    values = poller.last_values()
    shown = [name for prefix in LIVE_VALUE_PREFIXES for name in sorted(values) if name.startswith(prefix)]
    achieved = meter.rate(machine_id, poller.stats.status_reads, now)
    return {
        "id": machine_id,
        "endpoint": poller.machine.endpoint,
        "connected": bool(poller.online),
        "since": _iso(poller.online_changed_at),
        "series": sysinfo.model_name if sysinfo is not None else (poller.machine.series or ""),
        "planned_hz": round(1.0 / poller.machine.poll.periods.status, 2),
        "achieved_hz": None if achieved is None else round(achieved, 2),
        "last_error": poller.last_error,
        "failing": failing_functions(poller),
        "dropped": poller.dropped,
        "alarms": [{"number": a.number, "type": a.type, "axis": a.axis, "message": a.message}
                   for a in poller.active_alarms],
        "values": [{"name": name, "value": value_text(values[name].value),
                    "quality": values[name].quality.name} for name in shown],
    }


def failing_functions(poller: Any) -> list[dict[str, Any]]:
    """The functions whose reads fail now, with since when and how often (stats.failing)."""
    return [{"function": function, "since": _iso(trouble.since), "errors": trouble.errors, "error": trouble.error}
            for function, trouble in sorted(poller.stats.failing.items())]


def failing_text(failing: Any) -> str:
    return f"{failing['function']} failing since {failing['since']} ({failing['errors']} errors): {failing['error']}"


def status_document(daemon: DaemonView, meter: RateMeter) -> dict[str, Any]:
    """What the page shows, as JSON-ready data."""
    now = time.monotonic()
    pollers: Mapping[str, Any] = dict(daemon.pollers)
    config = getattr(daemon, "config", None)
    machines = [_machine(mid, poller, meter, now) for mid, poller in sorted(pollers.items())]
    return {
        "version": __version__,
        "generated_at": _iso(time.time()),
        "gateway": {
            "broker_connected": bool(daemon.publisher.connected),
            "spool_depth": spool_depth(daemon),
            "writes_enabled": bool(config.writes.enabled) if config is not None else False,
            "machines": len(machines),
            "machines_connected": sum(1 for m in machines if m["connected"]),
        },
        "machines": machines,
    }


# ---- HTML -------------------------------------------------------------------------------------------------

_STYLE = """
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222;background:#fafafa}
h1{font-size:1.3em;margin:0 0 .3em}table{border-collapse:collapse;width:100%;background:#fff}
th,td{border:1px solid #ddd;padding:.35em .5em;text-align:left;vertical-align:top}th{background:#f0f0f0}
.up{color:#0a7d2c;font-weight:600}.down{color:#b3261e;font-weight:600}.muted{color:#777}
.alarm{color:#b3261e}dl{display:grid;grid-template-columns:max-content auto;gap:.2em 1em;margin:.5em 0 1em}
dt{color:#555}dd{margin:0}small{color:#777}
"""

# Redraws the page from /status.json every second. Text goes in with textContent only (no HTML from data).
_SCRIPT = """
const cell = (row, text, cls) => { const td = row.insertCell(); td.textContent = text;
  if (cls) td.className = cls; return td; };
const rate = (m) => (m.achieved_hz === null ? "measuring" : m.achieved_hz.toFixed(2)) + " / "
  + m.planned_hz.toFixed(2) + " Hz";
let updates = 0;
function draw(doc) {
  const g = doc.gateway;
  document.getElementById("broker").textContent = g.broker_connected ? "connected" : "DOWN";
  document.getElementById("broker").className = g.broker_connected ? "up" : "down";
  document.getElementById("spool").textContent = g.spool_depth;
  document.getElementById("writes").textContent = g.writes_enabled ? "on" : "off";
  document.getElementById("count").textContent = g.machines_connected + " of " + g.machines + " connected";
  const body = document.getElementById("machines");
  body.replaceChildren();
  for (const m of doc.machines) {
    const row = body.insertRow();
    row.id = "machine-" + m.id;
    cell(row, m.id);
    cell(row, (m.connected ? "connected" : "offline") + " since " + m.since, m.connected ? "up" : "down");
    cell(row, m.series || "?");
    cell(row, rate(m));
    cell(row, m.values.map(v => v.name + " = " + v.value + (v.quality === "GOOD" ? "" : " [" + v.quality + "]"))
      .join("\\n") || "(none)").style.whiteSpace = "pre-line";
    cell(row, m.alarms.map(a => a.number + " " + a.message).join("\\n") || "none",
      m.alarms.length ? "alarm" : "muted").style.whiteSpace = "pre-line";
    cell(row, m.dropped.join(", ") || "none", m.dropped.length ? "" : "muted");
    const failing = m.failing.map(f => f.function + " failing since " + f.since + " (" + f.errors + " errors): "
      + f.error);
    cell(row, failing.concat(m.last_error ? [m.last_error] : []).join("\\n") || "none",
      failing.length ? "down" : (m.last_error ? "" : "muted")).style.whiteSpace = "pre-line";
  }
  updates += 1;
  document.body.dataset.updates = updates;
  document.getElementById("updated").textContent = "live, updated " + doc.generated_at + " (" + updates + ")";
}
async function refresh() {
  try { const r = await fetch("status.json", {cache: "no-store"}); draw(await r.json()); }
  catch (e) { document.getElementById("updated").textContent = "daemon not answering: " + e; }
}
setInterval(refresh, __REFRESH_MS__);
refresh();
""".replace("__REFRESH_MS__", str(REFRESH_MS))

_COLUMNS = ("machine", "CNC session", "series", "status reads achieved / planned", "live values", "active alarms",
            "dropped functions", "failing functions, last error")


def _row(machine: Mapping[str, Any]) -> str:
    e = html.escape
    rate = "measuring" if machine["achieved_hz"] is None else f"{machine['achieved_hz']:.2f}"
    values = "<br>".join(e(f"{v['name']} = {v['value']}" + ("" if v["quality"] == "GOOD" else f" [{v['quality']}]"))
                         for v in machine["values"]) or "(none)"
    alarms = "<br>".join(e(f"{a['number']} {a['message']}") for a in machine["alarms"])
    state = "connected" if machine["connected"] else "offline"
    cells = [
        e(machine["id"]),
        f"<span class=\"{'up' if machine['connected'] else 'down'}\">{state} since {e(machine['since'])}</span>",
        e(machine["series"] or "?"),
        f"{rate} / {machine['planned_hz']:.2f} Hz",
        values,
        f"<span class=\"alarm\">{alarms}</span>" if alarms else "<span class=\"muted\">none</span>",
        e(", ".join(machine["dropped"])) or "<span class=\"muted\">none</span>",
        _errors_cell(machine),
    ]
    return f"<tr id=\"machine-{e(machine['id'])}\">" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>"


def _errors_cell(machine: Mapping[str, Any]) -> str:
    e = html.escape
    lines = [f"<span class=\"down\">{e(failing_text(f))}</span>" for f in machine["failing"]]
    if machine["last_error"]:
        lines.append(e(machine["last_error"]))
    return "<br>".join(lines) or "<span class=\"muted\">none</span>"


def render_page(doc: Mapping[str, Any], top: str = "") -> str:
    """The whole page, filled in from `doc` (the script then keeps it current); `top` goes above the table
    (the plant page's fleet overview, edge.service.plant_page)."""
    g = doc["gateway"]
    rows = "\n".join(_row(m) for m in doc["machines"])
    broker = "<span id=\"broker\" class=\"{}\">{}</span>".format(
        "up" if g["broker_connected"] else "down", "connected" if g["broker_connected"] else "DOWN")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>focas-edge status</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{_STYLE}</style></head>
<body data-updates="0">
<h1>focas-edge {html.escape(doc["version"])}</h1>
<small id="updated">rendered {html.escape(doc["generated_at"])}; live updates need JavaScript</small>
<dl>
<dt>MQTT broker session</dt><dd>{broker}</dd>
<dt>spool depth</dt><dd id="spool">{g["spool_depth"]}</dd>
<dt>writes</dt><dd id="writes">{"on" if g["writes_enabled"] else "off"}</dd>
<dt>machines</dt><dd id="count">{g["machines_connected"]} of {g["machines"]} connected</dd>
</dl>
{top}
<table><thead><tr>{"".join(f"<th>{c}</th>" for c in _COLUMNS)}</tr></thead>
<tbody id="machines">
{rows}
</tbody></table>
<p><small>JSON: <a href="status.json">status.json</a> · <a href="healthz">healthz</a> ·
<a href="metrics">metrics</a></small></p>
<script>{_SCRIPT}</script>
</body></html>
"""


def page_json(doc: Mapping[str, Any]) -> bytes:
    return json.dumps(doc).encode() + b"\n"
