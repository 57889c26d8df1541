"""The optional local HTTP endpoint: `/healthz` for a load balancer or a probe, `/metrics` for Prometheus,
and a status page for people at `/` (edge.service.status_page, which polls `/status.json`).

Off by default (`http: {enabled: true}` turns it on; it binds 127.0.0.1:9108 unless told otherwise).
A tiny HTTP/1.1 server on the daemon's own event loop: a scrape reads the live poller and publisher
state on the loop thread, so it needs no locks and never sees a half-updated counter. One request per
connection (Connection: close), bounded header size and read time, GET and HEAD only.

The metrics are built at scrape time by a custom collector on a private CollectorRegistry (nothing
global, no default process metrics mixed in), and rendered by prometheus-client.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.exposition import CONTENT_TYPE_LATEST, generate_latest

from edge import __version__
from edge.collect import CYCLE_BUCKETS
from edge.service.daemon_view import DaemonView, spool_depth
from edge.service.status_gateway import broker_document, broker_text
from edge.service.status_page import RateMeter, page_json, render_page, status_document

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 5.0
MAX_HEADER_BYTES = 8192
_REASONS = {200: "OK", 404: "Not Found", 405: "Method Not Allowed", 400: "Bad Request", 503: "Service Unavailable"}


# ---- health ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Health:
    ok: bool
    broker_connected: bool
    machines: int
    machines_connected: int
    healthy_share: float
    reasons: tuple[str, ...] = ()

    def document(self) -> dict[str, Any]:
        return {"status": "ok" if self.ok else "unhealthy", "broker_connected": self.broker_connected,
                "machines": self.machines, "machines_connected": self.machines_connected,
                "healthy_share": self.healthy_share, "reasons": list(self.reasons)}


def assess_health(daemon: DaemonView, healthy_share: float) -> Health:
    """Healthy while the broker session is up and at least `healthy_share` of the machines are connected."""
    broker = bool(daemon.publisher.connected)
    total = len(daemon.pollers)
    connected = sum(1 for poller in daemon.pollers.values() if poller.online)
    reasons = []
    if not broker:
        reasons.append(f"the MQTT broker session is down ({broker_text(broker_document(daemon))})")
    share = connected / total if total else 1.0
    if share < healthy_share:
        down = sorted(mid for mid, poller in daemon.pollers.items() if not poller.online)
        reasons.append(f"{connected} of {total} machine(s) connected, at least {healthy_share:.0%} required; "
                       f"down: {', '.join(down)}")
    return Health(not reasons, broker, total, connected, healthy_share, tuple(reasons))


# ---- metrics --------------------------------------------------------------------------------------------


# Publisher figures that go down as well as up are gauges, never counters (a counter that falls reads as a
# reset). spool_rows is focas_edge_spool_depth.
PUBLISHER_GAUGES = {"unconfirmed_batches": "live batches sent but not yet confirmed by a delivery barrier"}


def cycle_histogram(buckets: Sequence[int]) -> list[tuple[str, float]]:
    """A poller's cycle-time counts as Prometheus cumulative buckets ("le" bound, count)."""
    running = 0
    out = []
    for bound, count in zip((*CYCLE_BUCKETS, float("inf")), buckets, strict=True):
        running += count
        out.append(("+Inf" if bound == float("inf") else repr(bound), float(running)))
    return out


class DaemonCollector:
    """A prometheus-client collector that reads the daemon's live state at every scrape."""

    def __init__(self, daemon: DaemonView) -> None:
        self.daemon = daemon

    def collect(self) -> Iterable[Metric]:
        pollers = dict(self.daemon.pollers)
        publisher = self.daemon.publisher
        info = GaugeMetricFamily("focas_edge_info", "focas-edge build information", labels=["version"])
        info.add_metric([__version__], 1)
        yield info
        broker = GaugeMetricFamily("focas_edge_broker_connected", "1 while the MQTT broker session is up")
        broker.add_metric([], 1 if publisher.connected else 0)
        yield broker
        yield from self._machine_metrics(pollers)
        yield from self._publish_metrics(publisher)
        spool = GaugeMetricFamily("focas_edge_spool_depth", "rows (one tick of one machine) waiting in the "
                                  "store-and-forward spool")
        spool.add_metric([], spool_depth(self.daemon))
        yield spool
        writes = CounterMetricFamily("focas_edge_writes", "remote writes by outcome", labels=["outcome"])
        for outcome, count in sorted(dict(getattr(self.daemon.commands, "counters", None) or {}).items()):
            writes.add_metric([str(outcome)], float(count))
        yield writes

    def _machine_metrics(self, pollers: Mapping[str, Any]) -> Iterable[Metric]:
        label = ["machine"]
        connected = GaugeMetricFamily("focas_edge_machine_connected", "1 while the CNC session is up",
                                      labels=label)
        ticks = CounterMetricFamily("focas_edge_poll_ticks", "poll cycles completed", labels=label)
        overruns = CounterMetricFamily("focas_edge_poll_overruns", "ticks that took longer than their period",
                                       labels=label)
        skipped = CounterMetricFamily("focas_edge_poll_skipped_ticks", "ticks skipped after an overrun",
                                      labels=label)
        errors = CounterMetricFamily("focas_edge_cnc_errors", "failed reads by function and EW code or error "
                                     "class", labels=["machine", "function", "code"])
        failing = GaugeMetricFamily("focas_edge_function_failing", "1 while a function's reads fail (until it "
                                    "answers again)", labels=["machine", "function"])
        skew = GaugeMetricFamily("focas_edge_clock_skew_seconds", "CNC clock minus gateway clock", labels=label)
        cycle = HistogramMetricFamily("focas_edge_poll_cycle_seconds", "wall time of one poll cycle (one "
                                      "batched request)", labels=label)
        for machine_id, poller in sorted(pollers.items()):
            stats = poller.stats
            connected.add_metric([machine_id], 1 if poller.online else 0)
            ticks.add_metric([machine_id], stats.ticks)
            overruns.add_metric([machine_id], stats.overruns)
            skipped.add_metric([machine_id], stats.skipped)
            for (function, code), count in sorted(stats.errors.items()):
                errors.add_metric([machine_id, function, code], count)
            for function in sorted(stats.failing):
                failing.add_metric([machine_id, function], 1)
            skew_s = poller.clock.skew_s
            if skew_s is not None:
                skew.add_metric([machine_id], skew_s)
            cycle.add_metric([machine_id], cycle_histogram(stats.cycle_buckets), stats.cycle_total_s)
        yield from (connected, ticks, overruns, skipped, errors, failing, skew, cycle)

    def _publish_metrics(self, publisher: Any) -> Iterable[Metric]:
        counters = dict(publisher.counters)
        messages = CounterMetricFamily("focas_edge_mqtt_messages", "MQTT messages by outcome",
                                       labels=["outcome"])
        for outcome in ("published", "dropped"):
            messages.add_metric([outcome], float(counters.pop(outcome, 0)))
        yield messages
        counters.pop("spool_rows", None)
        conflicts = CounterMetricFamily("focas_edge_identity_conflicts", "evidence that another gateway uses this "
                                        "gateway's Sparkplug id or client id on the broker (edge.publish.identity)")
        conflicts.add_metric([], float(counters.pop("identity_conflicts", 0)))
        yield conflicts
        for name, help_text in PUBLISHER_GAUGES.items():
            gauge = GaugeMetricFamily(f"focas_edge_{name}", help_text)
            gauge.add_metric([], float(counters.pop(name, 0)))
            yield gauge
        events = CounterMetricFamily("focas_edge_publisher_events", "publisher events (births, rebirths, "
                                     "commands, connects, ...)", labels=["event"])
        for name, count in sorted(counters.items()):
            events.add_metric([name], float(count))
        yield events


def metrics_registry(daemon: DaemonView) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(DaemonCollector(daemon))
    return registry


# ---- the server -----------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Response:
    status: int
    content_type: str
    body: bytes


class StatusServer:
    """`await StatusServer(daemon, host, port, healthy_share).start()`; `await stop()` when done."""

    def __init__(self, daemon: DaemonView, host: str = "127.0.0.1", port: int = 9108,
                 healthy_share: float = 0.5) -> None:
        self.daemon = daemon
        self.host = host
        self.requested_port = port
        self.healthy_share = healthy_share
        self.registry = metrics_registry(daemon)
        self.rates = RateMeter()
        self._server: asyncio.Server | None = None
        self._connections: set[asyncio.Task[None]] = set()

    @property
    def port(self) -> int:
        """The bound port (useful with port 0)."""
        if self._server is None or not self._server.sockets:
            return self.requested_port
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._serve, self.host, self.requested_port,
                                                  limit=MAX_HEADER_BYTES)
        log.info("status endpoint listening host=%s port=%d paths=/,/status.json,/healthz,/metrics", self.host,
                 self.port)

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is None:
            return
        server.close()
        for task in list(self._connections):
            task.cancel()
        await asyncio.gather(*self._connections, return_exceptions=True)
        with contextlib.suppress(Exception):
            await asyncio.wait_for(server.wait_closed(), 2.0)

    def respond(self, method: str, path: str) -> Response:
        """The answer to one request (no I/O; the tests call it directly too)."""
        if method not in ("GET", "HEAD"):
            return _json(405, {"error": f"method {method} not allowed; expected GET or HEAD"})
        route = path.split("?", 1)[0]
        if route == "/healthz":
            health = assess_health(self.daemon, self.healthy_share)
            return _json(200 if health.ok else 503, health.document())
        if route == "/metrics":
            return Response(200, CONTENT_TYPE_LATEST, generate_latest(self.registry))
        if route in ("/", "/status.json"):
            doc = status_document(self.daemon, self.rates)
            if route == "/":
                return Response(200, "text/html; charset=utf-8", render_page(doc).encode())
            return Response(200, "application/json", page_json(doc))
        return _json(404, {"error": f"no such path {route!r}; expected /, /status.json, /healthz or /metrics"})

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections.add(task)
        try:
            response, method = await self._answer(reader)
            head = (f"HTTP/1.1 {response.status} {_REASONS.get(response.status, 'Status')}\r\n"
                    f"Content-Type: {response.content_type}\r\nContent-Length: {len(response.body)}\r\n"
                    "Connection: close\r\nCache-Control: no-store\r\n\r\n")
            writer.write(head.encode("ascii") + (b"" if method == "HEAD" else response.body))
            await asyncio.wait_for(writer.drain(), REQUEST_TIMEOUT_S)
        except (OSError, TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ValueError):
            pass  # the client went away or sent junk: nothing to answer
        finally:
            self._connections.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    async def _answer(self, reader: asyncio.StreamReader) -> tuple[Response, str]:
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), REQUEST_TIMEOUT_S)
        request_line = head.split(b"\r\n", 1)[0].decode("latin-1")
        parts = request_line.split()
        if len(parts) != 3 or not parts[2].startswith("HTTP/"):
            return _json(400, {"error": f"expected 'METHOD PATH HTTP/1.x', got {request_line[:80]!r}"}), "GET"
        method, path = parts[0], parts[1]
        try:
            return self.respond(method, path), method
        except Exception as exc:  # a broken scrape must not take the daemon down
            log.exception("status endpoint failed path=%s", path)
            return _json(503, {"error": f"internal error: {exc!r}"}), method


def _json(status: int, document: dict[str, Any]) -> Response:
    return Response(status, "application/json", json.dumps(document).encode() + b"\n")
