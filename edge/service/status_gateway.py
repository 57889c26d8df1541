"""The gateway itself on the status page, in status.json and in systemd's STATUS= line.

Which gateway this is (edge node id, version, host name, uptime, config file, its local time and UTC
offset) and how its broker session is: connected since, or down since with the last error. A person at
the gateway otherwise has to find the journal to learn why nothing reaches the MES.

Times are local with their offset (edge.service.value_freshness.local_iso): the person reading them
stands in the plant, not in UTC.
"""

from __future__ import annotations

import html
import socket
from typing import Any

from edge import __version__
from edge.service.daemon_view import DaemonView
from edge.service.value_freshness import local_iso


def uptime_text(seconds: float) -> str:
    """3d 04:05:06 / 04:05:06: the gateway's uptime for people."""
    s = int(seconds)
    days, rest = divmod(s, 86400)
    clock = f"{rest // 3600:02d}:{rest % 3600 // 60:02d}:{rest % 60:02d}"
    return f"{days}d {clock}" if days else clock


def gateway_identity(daemon: DaemonView, now: float) -> dict[str, Any]:
    """Which gateway answers: what a person reports when they call for help."""
    settings = getattr(daemon.publisher, "settings", None)
    group = getattr(settings, "group_id", "")
    node = getattr(settings, "edge_node_id", "")
    uptime = float(getattr(daemon, "uptime_s", 0.0))
    config_path = getattr(daemon, "config_path", None)
    return {
        "edge_node_id": f"{group}/{node}" if group else str(node),
        "version": __version__,
        "host_name": socket.gethostname(),
        "uptime_s": round(uptime),
        "started_at": local_iso(now - uptime),
        "config_file": str(config_path) if config_path is not None else "",
        "local_time": local_iso(now),
    }


def broker_document(daemon: DaemonView) -> dict[str, Any]:
    """The broker session(s): address, connected since / down since, the last error.

    With Sparkplug and JSON both on there are two connections; the summary is down while either is, with
    the earliest down-since and that connection's error.
    """
    states_of = getattr(daemon.publisher, "broker_states", None)
    states = list(states_of()) if callable(states_of) else []
    connections = [{"format": fmt, "address": s.address, "client_id": s.client_id, "connected": s.connected,
                    "since": local_iso(s.since), "last_error": s.last_error, "reason": s.reason,
                    "failed_attempts": s.failed_attempts} for fmt, s in states]
    down = [s for _, s in states if not s.connected]
    first = min(down, key=lambda s: s.since) if down else (states[0][1] if states else None)
    return {
        "address": first.address if first is not None else "",
        "connected": bool(states) and not down,
        "connected_since": local_iso(max(s.since for _, s in states)) if states and not down else None,
        "down_since": local_iso(first.since) if down and first is not None else None,
        "last_error": first.last_error if first is not None else "",
        "connections": connections,
    }


def broker_text(broker: dict[str, Any]) -> str:
    """One line: 'broker 10.0.0.5:1883 connected since ...' or '... DOWN since ... (last error)'."""
    if broker["connected"]:
        return f"broker {broker['address']} connected since {broker['connected_since']}"
    text = f"broker {broker['address']} DOWN since {broker['down_since']}"
    return text + (f": {broker['last_error']}" if broker["last_error"] else "")


def systemd_status(daemon: DaemonView) -> str:
    """The STATUS= line `systemctl status` shows: machines connected and the broker session."""
    pollers = dict(daemon.pollers)
    connected = sum(1 for p in pollers.values() if p.online)
    return f"{connected} of {len(pollers)} machine(s) connected; {broker_text(broker_document(daemon))}"


# ---- on the page -----------------------------------------------------------------------------------------

_FIELDS = (("edge node", "edge_node_id"), ("version", "version"), ("host", "host_name"),
           ("config file", "config_file"), ("started", "started_at"), ("gateway time", "local_time"))


def render_gateway_block(gateway: dict[str, Any], broker: dict[str, Any]) -> str:
    """The gateway's identity and its broker session, as a definition list (the script keeps it current)."""
    e = html.escape
    rows = [f"<dt>{label}</dt><dd id=\"gw-{key}\">{e(str(gateway[key]) or '(none)')}</dd>" for label, key in _FIELDS]
    rows.insert(5, f"<dt>uptime</dt><dd id=\"gw-uptime\">{uptime_text(gateway['uptime_s'])}</dd>")
    up = broker["connected"]
    rows.append(f"<dt>MQTT broker</dt><dd id=\"broker-detail\" class=\"{'up' if up else 'down'}\">"
                f"{e(broker_text(broker))}</dd>")
    return "<dl id=\"gateway\">\n" + "\n".join(rows) + "\n</dl>"


# Redraws the block from status.json (called by the page's draw()); text goes in with textContent only.
GATEWAY_SCRIPT = """
const uptimeText = (s) => { const d = Math.floor(s / 86400), r = s % 86400, p = (n) => String(n).padStart(2, "0");
  const t = p(Math.floor(r / 3600)) + ":" + p(Math.floor(r % 3600 / 60)) + ":" + p(r % 60);
  return d ? d + "d " + t : t; };
const brokerText = (b) => b.connected ? "broker " + b.address + " connected since " + b.connected_since
  : "broker " + b.address + " DOWN since " + b.down_since + (b.last_error ? ": " + b.last_error : "");
function drawGateway(doc) {
  const id = doc.gateway.identity, b = doc.gateway.broker;
  for (const key of ["edge_node_id", "version", "host_name", "config_file", "started_at", "local_time"]) {
    document.getElementById("gw-" + key).textContent = String(id[key]) || "(none)";
  }
  document.getElementById("gw-uptime").textContent = uptimeText(id.uptime_s);
  const detail = document.getElementById("broker-detail");
  detail.textContent = brokerText(b);
  detail.className = b.connected ? "up" : "down";
}
"""
