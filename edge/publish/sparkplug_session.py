"""The Sparkplug B 3.0 edge-node session over its own MQTT connection (shared/docs/sparkplug.md §1.2-1.9).

Rules this module keeps:
1. Every CONNECT carries a fresh NDEATH Will with the next bdSeq (persisted first, edge.publish.bdseq).
2. NCMD, DCMD (and STATE) subscriptions are acknowledged before the NBIRTH; with a primary host configured,
   births wait for its STATE online, and its STATE offline means NDEATH, DISCONNECT and a new session.
3. Every message is built (seq assigned, edge.publish.node) and handed to paho in the same synchronous
   step, so this session is the single writer of seq and wire order equals seq order.
4. A rebirth request (NCMD Node Control/Rebirth) stops DATA at once; births follow at most once per
   `rebirth_min_interval_s`, later requests in that window coalesce.
5. DATA goes out live only while born, the device is online and born since the NBIRTH (its DBIRTH sent)
   and the link is not suspect; otherwise it is held (edge.publish.link) and replayed after the births,
   without what the births already carried. The NBIRTH goes out at once, the DBIRTHs over the next loop
   turns (`_dbirths`), so 1,000 machines' births do not hold the live ticks for one long turn.
6. Our own NBIRTH and NDEATH topics are watched: another session's birth or death there, or the broker
   taking our client id, is an identity conflict (edge.publish.identity): one ERROR, then reconnects and
   rebirths at most once a minute while it lasts.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from edge.publish.aliases import AliasMap
from edge.publish.bdseq import BdSeqCounter
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.holding import SpoolWriter
from edge.publish.identity import IdentityGuard, bdseq_of
from edge.publish.inbound import CommandHandlers, CommandSource, DeviceCommands, RefusedMetric
from edge.publish.link import DeliveryLink
from edge.publish.mqtt import InboundMessage, MqttConnection, MqttUnavailable, Will
from edge.publish.node import Outgoing, ReleasedEvents, SparkplugNode
from edge.publish.node_commands import CommandIgnored, DeviceCommand, RebirthRequested
from edge.publish.primary_host import PrimaryHost, StateVerdict
from edge.publish.replay import Replayer
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.settings import PublishSettings
from edge.publish.state_store import StateStore
from edge.publish.tasks import BackgroundTasks, awaited
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)

# DBIRTHs are built for this long a loop turn, then the loop goes to the live ticks: at ~0.2 ms a DBIRTH of
# 100 metrics (edge.publish.birth_bytes), 1,000 machines' births take two turns; the replay's slices are as long.
BIRTH_SLICE_S = 0.1
# Before each DBIRTH, wait while the connection holds more than this for the broker (this turn's packets
# included): a 100 ms slice is ~500 DBIRTHs, ~3 MB of payloads, packets and writes in the C heap at once.
BIRTH_HELD_BYTES = 1024 * 1024


class SparkplugSession:
    """One Sparkplug edge node (+ devices): its connection, births and deaths, STATE, rebirths and commands."""

    def __init__(self, settings: PublishSettings, store: StateStore, clock: Callable[[], int], *,
                 writer: SpoolWriter, policy: ForwardingPolicy, counters: Counter[str], tasks: BackgroundTasks,
                 handlers: CommandHandlers, guard: IdentityGuard) -> None:
        self.settings = settings
        self.guard = guard
        self._counters = counters
        self._tasks = tasks
        self._handlers = handlers
        # The gateway's metrics as of now (the daemon's node_metrics): read again for every NBIRTH, so a
        # birth states the machines configured and connected at that moment, not the last NDATA's values.
        self.node_metrics_source: Callable[[], Sequence[Sample]] | None = None
        self.delivered = DeliveredValues()  # what this Sparkplug connection sent: replay skips it
        self.bdseq = BdSeqCounter(store)
        if self.bdseq.last is not None:
            guard.used_bdseq(self.bdseq.last)  # the previous run's Will may still come
        self.node = SparkplugNode(settings.group_id, settings.edge_node_id, AliasMap(store), clock)
        self.host = PrimaryHost(settings.primary_host_id) if settings.primary_host_id else None
        self.link = DeliveryLink("sparkplug", writer, counters, policy, tasks, self.delivered)
        self.replay = Replayer(self.link, self, writer.spool, counters, tasks, self.delivered)
        self._subscribed = False
        self._rebirth_handle: asyncio.TimerHandle | None = None
        self._last_rebirth = -1e9

    # -- lifecycle -----------------------------------------------------------------------------------

    def start(self) -> None:
        if self.link.conn is None:
            client_id = self.settings.client_id
            guard = self.guard
            conn = MqttConnection(self.settings, client_id, before_connect=self._will,
                                  on_connected=self._connected, on_disconnected=self._disconnected,
                                  on_message=self.handle_message,
                                  on_lost=lambda lasted, reason: guard.session_lost(client_id, lasted, reason),
                                  min_delay=guard.reconnect_floor_s)
            self.link.attach(conn, client_id)
            conn.start()

    @property
    def state(self) -> str:
        """disconnected, subscribing, waiting_for_host, rebirthing or born."""
        conn = self.link.conn
        if conn is None or not conn.connected:
            return "disconnected"
        if self.node.holding:
            return "rebirthing"
        if self.node.born:
            return "born"
        return "subscribing" if not self._subscribed else "waiting_for_host"

    async def stop(self) -> None:
        """DDEATH every online device, NDEATH (confirmed), DISCONNECT (MQTT 5: reason 0x04)."""
        spb = self.link.detach()
        if spb is None:
            return
        last: Outgoing | None = None
        if spb.connected:
            messages = self.node.shutdown()
            if messages:
                last = messages[-1]  # the NDEATH: confirmed before the DISCONNECT
                self.link.send(spb, messages[:-1])
        else:
            self.node.shutdown()
        await self.link.confirm_then_disconnect(spb, last, with_will=True)

    # -- what the publisher fans out -----------------------------------------------------------------

    def set_node_metrics(self, samples: Sequence[Sample]) -> None:
        self.link.send(self.link.conn, self.node.set_node_metrics(samples))

    def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        births = self.node.device_online(device_id, specs, samples)
        if self.link.send(self.link.conn, births) and births:
            self._record_birth(device_id)
        if self.node.live:
            self.replay.kick()  # rows this device left in the spool

    def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        node = self.node
        if self._live(device_id):
            self.link.send_live(node.device_data(device_id, samples), device_id, "data", samples)
        else:
            node.device_data(device_id, samples)  # births will carry the latest values
            self.link.hold(device_id, "data", samples)

    def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        if self._live(device_id):
            self.link.send_live(self.node.device_events(device_id, events), device_id, "events", events)
        else:
            self.link.hold(device_id, "events", events)

    def device_offline(self, device_id: str) -> None:
        self.link.send(self.link.conn, self.node.device_offline(device_id))

    def _live(self, device_id: str) -> bool:
        """Sparkplug DATA for this device can go out live now."""
        conn = self.link.conn
        return conn is not None and conn.connected and self.node.is_live(device_id) and not self.link.suspect

    # -- the MQTT session ----------------------------------------------------------------------------

    def _will(self, previous_unsent: bool) -> Will:
        """Before every CONNECT (in the connect worker thread): next bdSeq (persisted) in a fresh NDEATH Will."""
        bdseq = self.bdseq.next_for_connect(previous_unsent)
        self.guard.used_bdseq(bdseq)
        will = self.node.will(bdseq)
        return Will(will.topic, will.payload, qos=will.qos, retain=will.retain, tag=bdseq)

    def _connected(self, tag: object) -> None:
        assert isinstance(tag, int), "the Sparkplug Will always carries its bdSeq"
        self.link.connection_up()
        self._subscribed = False
        self.delivered.connection_lost()
        self.node.session_started(tag)
        if self.host is not None:
            self.host.new_session()
        self._tasks.spawn(self._subscribe(self.link.session))
        self.link.start_probing(self.replay.drain_waiting_rows)

    async def _subscribe(self, session: int) -> None:
        conn = self.link.conn
        if conn is None:
            return
        topics = [(self.node.ncmd_topic, 1), (self.node.dcmd_topic_filter, 1)]
        if self.host is not None:
            topics.append((self.host.topic, 1))
        try:
            await conn.subscribe(topics, timeout=self.settings.connect_timeout_s)
        except MqttUnavailable as exc:
            if session == self.link.session:
                log.error("Sparkplug subscriptions failed, reconnecting error=%s", exc)
                conn.drop_socket()
            return
        if session != self.link.session:
            return
        await self._watch_identity(conn)
        if session != self.link.session:
            return
        self._subscribed = True
        self._maybe_birth()

    async def _watch_identity(self, conn: MqttConnection) -> None:
        """Subscribe to our own NBIRTH/NDEATH (another session's there is a conflict); a broker that refuses
        it (an ACL) costs the detection, not the session."""
        try:
            await conn.subscribe([(self.node.nbirth_topic, 0), (self.node.ndeath_topic, 0)],
                                 timeout=self.settings.connect_timeout_s)
        except MqttUnavailable as exc:
            log.warning("cannot watch this node's own NBIRTH/NDEATH, identity conflicts are detected by "
                        "session take-overs only error=%s", exc)

    def _maybe_birth(self) -> None:
        conn = self.link.conn
        if conn is None or not conn.connected or not self._subscribed or self.node.born or self._tasks.stopping:
            return
        if self.host is not None and not self.host.online:
            log.info("waiting for primary host STATE online host=%s", self.host.host_id)
            return
        self._counters["births"] += 1
        self._send_births()

    def _disconnected(self) -> None:
        self.link.connection_down()
        self._subscribed = False
        self.cancel_rebirth()
        self.node.session_lost()
        self.delivered.connection_lost()

    # -- inbound: STATE, NCMD, DCMD ------------------------------------------------------------------

    def handle_message(self, msg: InboundMessage) -> None:
        if self.host is not None and msg.topic == self.host.topic:
            self._state_message(msg)
            return
        if msg.topic == self.node.nbirth_topic:
            self.guard.nbirth_seen(msg.payload, bdseq_of(msg.payload), self.node.bdseq)
            return
        if msg.topic == self.node.ndeath_topic:
            self.guard.ndeath_seen(bdseq_of(msg.payload), self.node.bdseq)
            return
        writes: list[tuple[str, object]] = []
        refused: list[RefusedMetric] = []
        device_id: str | None = None
        for event in self.node.parse_command(msg.topic, msg.payload):
            if isinstance(event, RebirthRequested):
                self._rebirth_requested()
            elif isinstance(event, DeviceCommand):
                device_id = event.device_id
                writes.append((event.metric_name, event.value))
            elif isinstance(event, CommandIgnored):
                self._counters["unknown_commands" if event.unknown else "rejected_commands"] += 1
                if event.device_id is not None and event.code is not None:
                    device_id = event.device_id
                    refused.append(RefusedMetric(event.metric, event.code, event.reason))
                else:
                    log.warning("Sparkplug command ignored topic=%s reason=%s", msg.topic, event.reason)
        if device_id is not None:
            self._dispatch_device_commands(DeviceCommands(device_id, tuple(writes), tuple(refused),
                                                          len(msg.payload)), msg)

    def _state_message(self, msg: InboundMessage) -> None:
        assert self.host is not None
        verdict = self.host.on_state(msg.topic, msg.payload)
        if verdict is StateVerdict.ONLINE:
            self._maybe_birth()
        elif verdict is StateVerdict.OFFLINE and self.node.born and not self._tasks.stopping:
            self._tasks.spawn(self._primary_host_offline())

    async def _primary_host_offline(self) -> None:
        """§1.3: NDEATH at once, DISCONNECT, then connect again (new bdSeq) and wait for STATE online."""
        conn = self.link.conn
        if conn is None:
            return
        log.warning("primary host offline: NDEATH and reconnect host=%s",
                    self.host.host_id if self.host else None)
        await self.link.settle()
        ndeath = self.node.ndeath()
        self.node.session_lost()
        self.cancel_rebirth()
        mark = self.link.outbox.mark()  # no live data after this: the node is not live
        sent = None if self.link.suspect else self.delivered.mark()
        if await self.link.publish_final(conn, ndeath) and sent is not None:
            self.link.outbox.confirm(mark)  # the NDEATH's PUBACK proves the data before it arrived
            self.delivered.proven(sent)
        await conn.stop(with_will=True)
        if not self._tasks.stopping and self.link.conn is conn:
            conn.start()

    def _rebirth_requested(self) -> None:
        """NCMD Node Control/Rebirth: stop DATA now; births at once, then at most once per interval."""
        self._counters["rebirth_requests"] += 1
        if self._rebirth_handle is not None:
            self._counters["rebirths_coalesced"] += 1
            return
        if not self.node.request_rebirth():
            return  # not born yet: the session's own births are still to come
        interval = self.guard.rebirth_interval_s(self.settings.rebirth_min_interval_s)
        delay = max(0.0, self._last_rebirth + interval - time.monotonic())
        self._rebirth_handle = asyncio.get_running_loop().call_later(delay, self._rebirth)

    def _rebirth(self) -> None:
        self._rebirth_handle = None
        if not self.node.born:
            return
        self._last_rebirth = time.monotonic()
        self._counters["rebirths"] += 1
        self._send_births()

    def _send_births(self) -> None:
        """The NBIRTH now (the node metrics refreshed first: not live yet, recorded, not sent), then the
        DBIRTHs over the next loop turns (`_dbirths`), which kick the replay after the last one (a probe
        round may start it sooner: it then sends the rows of the devices born so far, and looks again)."""
        conn = self.link.conn
        if self.node_metrics_source is not None:
            self.node.set_node_metrics(self.node_metrics_source())
        nbirth = self.node.nbirth()
        self.guard.sent_birth(nbirth.payload)  # its echo on our subscription is ours
        if not self.link.send(conn, (nbirth,)):
            return
        assert conn is not None
        self._tasks.spawn(self._dbirths(conn, self.link.session, self.node.generation))

    async def _dbirths(self, conn: MqttConnection, session: int, generation: int) -> None:
        """Each online device's DBIRTH (then the events a rebirth held for it), BIRTH_SLICE_S of them a loop
        turn: 1,000 DBIRTHs built at once held the loop ~0.9 s (protobuf) and ~7 MB of payloads at 1,000 machines.
        What each carries is recorded so the replay does not repeat it. A device's live DATA is held
        (spooled) until its DBIRTH (edge.publish.node: born_in); a newer NBIRTH, a rebirth request or a lost
        session ends this. The replay starts after the last DBIRTH."""
        node, link = self.node, self.link

        def current() -> bool:
            return session == link.session and conn.connected and node.generation == generation and node.live

        started = slice_from = time.monotonic()
        pending = node.unborn_devices()
        for device_id in pending:
            if conn.held > BIRTH_HELD_BYTES and current():  # ~150 DBIRTHs: let the socket take them first
                await conn.wait_for_room(BIRTH_HELD_BYTES // 2)
                slice_from = time.monotonic()
            elif time.monotonic() - slice_from > BIRTH_SLICE_S:
                await asyncio.sleep(0)
                slice_from = time.monotonic()
            if not current():
                return
            births = node.dbirth(device_id)
            if not births:
                continue  # went offline, or born meanwhile (device_online)
            released = node.release_held_events(device_id)
            births.extend(r.message for r in released)
            if not link.send(conn, births):
                return
            self._record_birth(device_id)
            self._record_released(released)
        if not current():
            return
        # The rest: events of devices born meanwhile (device_online) go out, those of devices gone offline not.
        released = node.release_held_events()
        if link.send(conn, [r.message for r in released]):
            self._record_released(released)
        log.info("births sent devices=%d seconds=%.2f", len(pending), time.monotonic() - started)
        self.replay.kick()

    def _record_birth(self, device_id: str) -> None:
        record = self.node.birth_record(device_id)
        if record is not None:
            self.delivered.record_birth_slots(device_id, *record)

    def _record_released(self, released: Sequence[ReleasedEvents]) -> None:
        """The held events that went out after the births: the replay does not send them again."""
        for r in released:
            self.delivered.record(r.device_id, r.samples)

    def cancel_rebirth(self) -> None:
        if self._rebirth_handle is not None:
            self._rebirth_handle.cancel()
            self._rebirth_handle = None

    def _dispatch_device_commands(self, commands: DeviceCommands, msg: InboundMessage) -> None:
        """One DCMD to the command layer, whole; its refused metrics are logged in one line, not one each."""
        if commands.refused:
            first = commands.refused[0]
            log.warning("DCMD metrics refused topic=%s refused=%d of=%d first=%s reason=%s", msg.topic,
                        len(commands.refused), commands.metric_count, first.code, first.reason)
        handler = self._handlers.device
        if handler is None:
            self._counters["rejected_commands"] += len(commands.writes)
            log.warning("DCMD ignored: no command handler device=%s metrics=%d", commands.device_id,
                        commands.metric_count)
            return
        self._tasks.spawn(awaited(handler(commands, CommandSource("sparkplug", msg.topic))))

    # -- what the replay asks (edge.publish.replay.ReplayTarget) -------------------------------------

    def replay_ready(self) -> bool:
        return self.node.live

    def replay_devices(self) -> list[str] | None:
        return [d for d in self.node.device_ids() if self.node.is_live(d)]

    def replay_accepts(self, device_id: str) -> bool:
        return self.node.is_live(device_id)

    def historical(self, entry: Any, samples: Sequence[Sample]) -> list[Outgoing]:
        return self.node.historical_data(entry.device_id, samples)

    def historical_rows(self, entry: Any, rows: Sequence[Sequence[Any]]) -> list[Outgoing]:
        return self.node.historical_rows(entry.device_id, rows)
