"""The facade the collector and the daemon call: machines' samples in, Sparkplug B and JSON over MQTT out.

Runs entirely on one asyncio loop. Nothing here blocks or raises because the broker is away: what cannot be
published goes to the `Spool` (edge.publish.spool.DiskSpool in the daemon; a counter by default).

The work is done by collaborators, one job each; this class builds them, fans each call out to the enabled
formats and sums their counters:
- edge.publish.sparkplug_session: the edge node's connection, births/deaths, STATE, rebirths, NCMD/DCMD;
- edge.publish.json_session: the JSON topics' connection, retained state, commands and replies;
- edge.publish.link: per connection, the outbox of unconfirmed live batches and the QoS 1 barrier probe;
- edge.publish.replay: per format, the paced replay of the spool after a reconnect;
- edge.publish.holding: the spool interface and the writer that survives a failing spool;
- edge.publish.tasks: the one owner of every background task.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from edge.publish.broker_trouble import BrokerState
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.holding import DroppingSpool, ReplaySpool, Spool, SpoolWriter
from edge.publish.identity import IdentityGuard
from edge.publish.inbound import (
    CommandHandlers,
    CommandSource,
    DeviceCommandHandler,
    JsonCommandHandler,
)
from edge.publish.json_session import JsonSession
from edge.publish.link import DeliveryLink
from edge.publish.mqtt import MqttConnection
from edge.publish.node import now_ms
from edge.publish.settings import PublishSettings
from edge.publish.sparkplug_session import SparkplugSession
from edge.publish.state_store import StateStore
from edge.publish.tasks import BackgroundTasks
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)


class Publisher:
    """One Sparkplug edge node (+ devices) and/or the JSON topics, over one or two MQTT connections."""

    def __init__(self, settings: PublishSettings, *, spool: Spool | None = None,
                 clock: Callable[[], int] = now_ms, forwarding: ForwardingPolicy | None = None) -> None:
        if not settings.formats or not set(settings.formats) <= {"sparkplug", "json"}:
            raise ValueError(f"formats {sorted(settings.formats)}: expected 'sparkplug' and/or 'json'")
        self.settings = settings
        store = StateStore(settings.state_dir)
        self._counters: Counter[str] = Counter()
        self._tasks = BackgroundTasks()
        self._handlers = CommandHandlers()
        self._writer = SpoolWriter(spool if spool is not None else DroppingSpool(), self._counters)
        policy = forwarding or ForwardingPolicy()
        self.identity = IdentityGuard(f"Sparkplug id {settings.group_id}/{settings.edge_node_id}"
                                      if "sparkplug" in settings.formats else f"client id {settings.client_id}")
        # The node always exists (bdSeq, aliases, counters); it connects only with the sparkplug format.
        self._sparkplug = "sparkplug" in settings.formats
        self._spb = SparkplugSession(settings, store, clock, writer=self._writer, policy=policy,
                                     counters=self._counters, tasks=self._tasks, handlers=self._handlers,
                                     guard=self.identity)
        self._json: JsonSession | None = None
        if "json" in settings.formats:
            self._json = JsonSession(settings, beside_sparkplug=self._sparkplug, writer=self._writer,
                                     policy=policy, counters=self._counters, tasks=self._tasks,
                                     handlers=self._handlers, guard=self.identity)

    # -- what the owner installs ---------------------------------------------------------------------

    @property
    def spool(self) -> Spool:
        return self._writer.spool

    @property
    def forwarding(self) -> ForwardingPolicy:
        """Delivery barrier and replay pacing; may be replaced before start() (tests use fast ones)."""
        return self._spb.link.policy

    @forwarding.setter
    def forwarding(self, policy: ForwardingPolicy) -> None:
        for link in self._links():
            link.policy = policy

    @property
    def on_device_command(self) -> DeviceCommandHandler | None:
        return self._handlers.device

    @on_device_command.setter
    def on_device_command(self, handler: DeviceCommandHandler | None) -> None:
        self._handlers.device = handler

    @property
    def on_json_command(self) -> JsonCommandHandler | None:
        return self._handlers.json

    @on_json_command.setter
    def on_json_command(self, handler: JsonCommandHandler | None) -> None:
        self._handlers.json = handler

    @property
    def after_replay(self) -> Callable[[], object] | None:
        """Called when a replay has emptied the spool (its rows, packets and steps are garbage then)."""
        return self._spb.replay.after_replay

    @after_replay.setter
    def after_replay(self, hook: Callable[[], object] | None) -> None:
        self._spb.replay.after_replay = hook
        if self._json is not None:
            self._json.replay.after_replay = hook

    @property
    def node_metrics_source(self) -> Callable[[], Sequence[Sample]] | None:
        """The gateway's metrics as of now, read again for every NBIRTH."""
        return self._spb.node_metrics_source

    @node_metrics_source.setter
    def node_metrics_source(self, source: Callable[[], Sequence[Sample]] | None) -> None:
        self._spb.node_metrics_source = source

    # -- lifecycle -----------------------------------------------------------------------------------

    async def start(self) -> None:
        """Start connecting (returns at once; births follow the connection). See wait_ready()."""
        self._tasks.stopping = False
        if self._sparkplug:
            self._spb.start()
        if self._json is not None:
            self._json.start()

    async def wait_ready(self, timeout: float = 10.0) -> bool:
        """Wait until every enabled format is connected (and Sparkplug born); False on timeout."""
        deadline = time.monotonic() + timeout
        while not self.ready:
            if time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.01)
        return True

    @property
    def ready(self) -> bool:
        spb_ok = not self._sparkplug or self._spb.node.born
        json_conn = self._json.link.conn if self._json is not None else None
        json_ok = json_conn is None or json_conn.connected
        return self.connected and spb_ok and json_ok

    @property
    def session_state(self) -> str:
        """Sparkplug session: disconnected, subscribing, waiting_for_host, rebirthing or born."""
        return self._spb.state

    def drop_connections(self) -> None:
        """Close the sockets without DISCONNECT, as a crash or cable pull would (tests, chaos drills)."""
        for conn in self._connections():
            conn.drop_socket()

    @property
    def connected(self) -> bool:
        conns = self._connections()
        return bool(conns) and all(c.connected for c in conns)

    def broker_states(self) -> list[tuple[str, BrokerState]]:
        """Each connection's broker session as (format, state): connected or down since when, the last error."""
        return [(link.fmt, link.conn.trouble.state()) for link in self._links() if link.conn is not None]

    async def stop(self) -> None:
        """DDEATH every online device, NDEATH, DISCONNECT (MQTT 5: reason 0x04); JSON: offline, retained."""
        self._tasks.stopping = True
        self._spb.cancel_rebirth()
        for link in self._links():
            await link.settle()
        await self._spb.stop()
        if self._json is not None:
            await self._json.stop()
        await self._tasks.cancel_all()
        for link in self._links():
            link.spool_outbox()

    def _links(self) -> list[DeliveryLink]:
        return [self._spb.link] if self._json is None else [self._spb.link, self._json.link]

    def _connections(self) -> list[MqttConnection]:
        return [link.conn for link in self._links() if link.conn is not None]

    # -- what the collector calls --------------------------------------------------------------------

    def set_node_metrics(self, samples: Sequence[Sample]) -> None:
        """Gateway metrics (version, machines connected, overruns, publish counts): NBIRTH, then NDATA."""
        if self._sparkplug:
            self._spb.set_node_metrics(samples)

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec],
                            samples: Sequence[Sample]) -> None:
        """A machine's session is up: DBIRTH with every metric; JSON online + retained state."""
        if self._sparkplug:
            self._spb.device_online(device_id, specs, samples)
        if self._json is not None:
            self._json.device_online(device_id, specs, samples)

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        """Changed values: DDATA (alias only, the CNC's timestamps); JSON retained state per value."""
        if not samples:
            return
        if self._sparkplug:
            self._spb.device_data(device_id, samples)
        if self._json is not None:
            self._json.device_data(device_id, samples)

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        """Alarm events (raise/clear, history): DDATA with the CNC occurrence time; JSON event topic."""
        if not events:
            return
        if self._sparkplug:
            self._spb.device_events(device_id, events)
        if self._json is not None:
            self._json.device_events(device_id, events)

    async def device_offline(self, device_id: str) -> None:
        """A machine's session is lost: DDEATH; JSON offline, retained."""
        if self._sparkplug:
            self._spb.device_offline(device_id)
        if self._json is not None:
            self._json.device_offline(device_id)

    async def publish_json_reply(self, device_id: str, payload: dict[str, Any] | list[dict[str, Any]],
                                 source: CommandSource) -> None:
        """A command reply: to the MQTT 5 response topic (with correlation data) or `<machine>/cmd/reply`."""
        conn = self._json.link.conn if self._json is not None else None
        if self._json is None or conn is None:
            self._counters["dropped"] += 1
            log.warning("JSON reply dropped: the json format is disabled device=%s", device_id)
            return
        self._json.reply(conn, device_id, payload, source)

    @property
    def counters(self) -> dict[str, int]:
        """Published/dropped messages, commands, rebirths, connects: a snapshot for node metrics and logs."""
        out = {k: 0 for k in ("published", "dropped", "unknown_commands", "rejected_commands",
                              "rebirth_requests", "rebirths", "rebirths_coalesced", "births")}
        out.update(self._counters)
        spb = self._spb
        spb_conn = spb.link.conn
        json_conn = self._json.link.conn if self._json is not None else None
        out["unknown_metrics"] = spb.node.unknown_metrics
        out["encode_errors"] = spb.node.encode_errors
        out["sparkplug_connects"] = spb_conn.connects if spb_conn is not None else 0
        out["json_connects"] = json_conn.connects if json_conn is not None else 0
        out["stale_state_ignored"] = spb.host.ignored if spb.host is not None else 0
        out["bdseq_persist_failures"] = spb.bdseq.persist_failures
        out["replay_duplicates_skipped"] = spb.delivered.skipped
        out["identity_conflicts"] = self.identity.count
        spool = self.spool
        dropped = getattr(spool, "dropped", None)
        if isinstance(dropped, int):
            out["samples_dropped"] = dropped
        if isinstance(spool, ReplaySpool):
            out["spool_rows"] = spool.pending()
        out["unconfirmed_batches"] = sum(len(link.outbox) for link in self._links())
        for key in ("spooled_batches", "replayed_messages", "replayed_rows", "suspect_dead", "probes"):
            out.setdefault(key, 0)
        return out

    @property
    def bdseq(self) -> int | None:
        """The bdSeq of the current (or last) Sparkplug session."""
        return self._spb.node.bdseq
