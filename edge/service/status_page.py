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
from typing import Any

from edge import __version__
from edge.service.daemon_view import DaemonView, spool_depth
from edge.service.status_gateway import GATEWAY_SCRIPT, broker_document, gateway_identity, render_gateway_block
from edge.service.value_freshness import freshness, local_iso

LIVE_VALUE_PREFIXES = ("Status/Run", "Status/Mode", "Program/Number", "Spindle/1/Speed", "Feed/Actual",
                       "Counters/Parts")
REFRESH_MS = 1000


def _iso(epoch_s: float) -> str:
    """Local time with its UTC offset: the person reading the page stands in the plant."""
    return local_iso(epoch_s)


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


def value_entries(poller: Any, values: Mapping[str, Any], names: list[str], wall_now: float) -> list[dict[str, Any]]:
    """Each value with its quality and age (edge.service.value_freshness): never GOOD from a dead session."""
    groups = poller.metric_groups()
    read_at = poller.read_at
    plan = poller.plan
    periods = plan.periods if plan is not None else {}
    online = bool(poller.online)
    out = []
    for name in names:
        sample = values[name]
        group = groups.get(name)
        fresh = freshness(sample.quality, online=online, last_read=read_at.get(group),
                          changed_at=sample.timestamp_ms / 1000, period_s=periods.get(group), now=wall_now)
        out.append({"name": name, "value": value_text(sample.value), "quality": fresh.quality,
                    "age_s": round(fresh.age_s, 1), "last_good": _iso(fresh.last_good)})
    return out


def value_text_line(value: Mapping[str, Any]) -> str:
    """`name = value`, and for a value that is not GOOD: its quality and since when it is not."""
    text = f"{value['name']} = {value['value']}"
    if value["quality"] == "GOOD":
        return text
    return text + f" [{value['quality']} since {value['last_good']}, {value['age_s']:.0f} s ago]"


def _machine(machine_id: str, poller: Any, meter: RateMeter, now: float, wall_now: float) -> dict[str, Any]:
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
        "values": value_entries(poller, values, shown, wall_now),
    }


def failing_functions(poller: Any) -> list[dict[str, Any]]:
    """The functions whose reads fail now, with since when and how often (stats.failing)."""
    return [{"function": function, "since": _iso(trouble.since), "errors": trouble.errors, "error": trouble.error}
            for function, trouble in sorted(poller.stats.failing.items())]


def failing_text(failing: Any) -> str:
    return f"{failing['function']} failing since {failing['since']} ({failing['errors']} errors): {failing['error']}"


def identity_conflict(publisher: Any) -> dict[str, Any] | None:
    """Another gateway on the broker with this one's identity (edge.publish.identity), while it lasts."""
    guard = getattr(publisher, "identity", None)
    conflict = guard.conflict if guard is not None else None
    if conflict is None:
        return None
    return {"identity": conflict.identity, "seen": conflict.seen, "since": _iso(conflict.since),
            "count": conflict.count}


def conflict_text(conflict: Mapping[str, Any] | None) -> str:
    """The page's line for it, HTML-escaped (the script writes the same text)."""
    if conflict is None:
        return "none"
    return html.escape(f"CONFLICT since {conflict['since']}: another gateway uses {conflict['identity']} "
                       f"({conflict['count']} times; last: {conflict['seen']})")


def status_document(daemon: DaemonView, meter: RateMeter) -> dict[str, Any]:
    """What the page shows, as JSON-ready data."""
    now, wall_now = time.monotonic(), time.time()
    pollers: Mapping[str, Any] = dict(daemon.pollers)
    config = getattr(daemon, "config", None)
    machines = [_machine(mid, poller, meter, now, wall_now) for mid, poller in sorted(pollers.items())]
    return {
        "version": __version__,
        "generated_at": _iso(wall_now),
        "gateway": {
            "identity": gateway_identity(daemon, wall_now),
            "broker": broker_document(daemon),
            "broker_connected": bool(daemon.publisher.connected),
            "spool_depth": spool_depth(daemon),
            "writes_enabled": bool(config.writes.enabled) if config is not None else False,
            "machines": len(machines),
            "machines_connected": sum(1 for m in machines if m["connected"]),
            "identity_conflict": identity_conflict(daemon.publisher),
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
dt{color:#555}dd{margin:0}small{color:#777}.stale{color:#999;font-style:italic}
"""

# Redraws the page from /status.json every second. Text goes in with textContent only (no HTML from data).
_SCRIPT = GATEWAY_SCRIPT + """
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
  const c = g.identity_conflict, identity = document.getElementById("identity-conflict");
  identity.textContent = c ? "CONFLICT since " + c.since + ": another gateway uses " + c.identity + " ("
    + c.count + " times; last: " + c.seen + ")" : "none";
  identity.className = c ? "down" : "muted";
  const body = document.getElementById("machines");
  body.replaceChildren();
  for (const m of doc.machines) {
    const row = body.insertRow();
    row.id = "machine-" + m.id;
    cell(row, m.id);
    cell(row, (m.connected ? "connected" : "offline") + " since " + m.since, m.connected ? "up" : "down");
    cell(row, m.series || "?");
    cell(row, rate(m));
    const values = cell(row, "");
    for (const v of m.values) {
      const line = document.createElement("div");
      line.textContent = v.name + " = " + v.value + (v.quality === "GOOD" ? "" : " [" + v.quality + " since "
        + v.last_good + ", " + Math.round(v.age_s) + " s ago]");
      if (v.quality !== "GOOD") line.className = "stale";
      values.appendChild(line);
    }
    if (!m.values.length) values.textContent = "(none)";
    cell(row, m.alarms.map(a => a.number + " " + a.message).join("\\n") || "none",
      m.alarms.length ? "alarm" : "muted").style.whiteSpace = "pre-line";
    cell(row, m.dropped.join(", ") || "none", m.dropped.length ? "" : "muted");
    const failing = m.failing.map(f => f.function + " failing since " + f.since + " (" + f.errors + " errors): "
      + f.error);
    cell(row, failing.concat(m.last_error ? [m.last_error] : []).join("\\n") || "none",
      failing.length ? "down" : (m.last_error ? "" : "muted")).style.whiteSpace = "pre-line";
  }
  drawGateway(doc);
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
    values = "".join(("<div>" if v["quality"] == "GOOD" else '<div class="stale">') + e(value_text_line(v))
                     + "</div>" for v in machine["values"]) or "(none)"
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


def render_page(doc: Mapping[str, Any]) -> str:
    """The whole page, filled in from `doc` (the script then keeps it current)."""
    g = doc["gateway"]
    rows = "\n".join(_row(m) for m in doc["machines"])
    conflict = g["identity_conflict"]
    conflict_class = "down" if conflict else "muted"
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
<dt>identity conflict</dt><dd id="identity-conflict" class="{conflict_class}">{conflict_text(conflict)}</dd>
</dl>
{render_gateway_block(g["identity"], g["broker"])}
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
