"""The facade the collector and the daemon call: machines' samples in, Sparkplug B and JSON over MQTT out.

Runs entirely on one asyncio loop. Every Sparkplug message is built (seq assigned) and handed to paho in
the same synchronous step, so this object is the single writer of seq and wire order equals seq order.
Nothing here blocks or raises because the broker is away: what cannot be published goes to the `Spool`
(edge.publish.spool.DiskSpool in the daemon; a counter by default).

Store and forward (docs/reliability.md): live DATA is QoS 0, so each connection keeps an outbox of live
batches until a QoS 1 probe's PUBACK confirms them (edge.publish.forwarding). A probe without PUBACK in
time, a failed publish or a lost connection makes the connection *suspect*: unconfirmed and new samples go
to the spool, the socket is dropped, and after the reconnect (and, for Sparkplug, the births) the spool is
replayed oldest first, paced, as separate historical messages, while live data flows at once.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal, Protocol, runtime_checkable

from edge.publish.aliases import AliasMap
from edge.publish.bdseq import BdSeqCounter
from edge.publish.forwarding import ForwardingPolicy, HeldBatch, Outbox
from edge.publish.json_topics import JsonTopics, encode
from edge.publish.mqtt import InboundMessage, MqttConnection, MqttUnavailable, Will, response_properties
from edge.publish.node import (
    CommandIgnored,
    DeviceCommand,
    Outgoing,
    RebirthRequested,
    SparkplugNode,
    now_ms,
)
from edge.publish.primary_host import PrimaryHost, StateVerdict
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.settings import PublishSettings
from edge.publish.state_store import StateStore
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)

PROBE_PREFIX = "focas-edge/probe"  # QoS 1 delivery barriers: <prefix>/<client id>, empty, not retained

Format = Literal["sparkplug", "json"]
SampleKind = Literal["data", "events"]
FORMATS: tuple[Format, ...] = ("sparkplug", "json")


@dataclass(frozen=True, slots=True)
class CommandSource:
    """Where a command came from, so the reply (if any) can go back the same way."""

    format: Format | Literal["opcua"]  # an OPC UA write has no reply topic: its Write response answers it
    topic: str
    response_topic: str | None = None  # MQTT 5 request/response
    correlation_data: bytes | None = None


class Spool(Protocol):
    """Receives what could not be published (broker away, no birth yet). A disk spool replays it later."""

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None: ...


@runtime_checkable
class ReplaySpool(Protocol):
    """A spool that can give its rows back for replay (edge.publish.spool.DiskSpool)."""

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None: ...

    def oldest(self, fmt: Format, limit: int, devices: Any = None) -> Sequence[Any]: ...

    def ack(self, ids: Sequence[int]) -> None: ...

    def pending(self, fmt: Format | None = None) -> int: ...


class DroppingSpool:
    """The default spool: counts what is lost."""

    def __init__(self) -> None:
        self.dropped = 0

    def hold(self, fmt: Format, device_id: str, kind: SampleKind, samples: Sequence[Sample]) -> None:
        self.dropped += len(samples)


DeviceCommandHandler = Callable[[str, str, object, CommandSource], Awaitable[None]]
JsonCommandHandler = Callable[[str, bytes, CommandSource], Awaitable[None]]
# A DCMD metric refused here (unknown device/metric, read-only, bad value): device, metric, code, reason.
RefusedCommandHandler = Callable[[str, str | None, str, str, CommandSource], None]


class Publisher:
    """One Sparkplug edge node (+ devices) and/or the JSON topics, over one or two MQTT connections."""

    def __init__(self, settings: PublishSettings, *, spool: Spool | None = None,
                 clock: Callable[[], int] = now_ms, forwarding: ForwardingPolicy | None = None) -> None:
        if not settings.formats or not set(settings.formats) <= {"sparkplug", "json"}:
            raise ValueError(f"formats {sorted(settings.formats)}: expected 'sparkplug' and/or 'json'")
        self.settings = settings
        self.spool: Spool = spool if spool is not None else DroppingSpool()
        self.on_device_command: DeviceCommandHandler | None = None
        # The gateway's metrics as of now (the daemon's node_metrics): read again for every NBIRTH, so a
        # birth states the machines configured and connected at that moment, not the last NDATA's values.
        self.node_metrics_source: Callable[[], Sequence[Sample]] | None = None
        self.on_json_command: JsonCommandHandler | None = None
        self.on_device_command_refused: RefusedCommandHandler | None = None
        store = StateStore(settings.state_dir)
        self._counters: Counter[str] = Counter()
        self._tasks: set[asyncio.Task[None]] = set()
        self._stopping = False
        # Store and forward, per format
        self.forwarding = forwarding or ForwardingPolicy()
        self._outbox: dict[Format, Outbox] = {"sparkplug": Outbox(), "json": Outbox()}
        self._suspect: dict[Format, bool] = {"sparkplug": False, "json": False}
        self._replaying: dict[Format, bool] = {"sparkplug": False, "json": False}
        self._replay_again: dict[Format, bool] = {"sparkplug": False, "json": False}
        self._json_session = 0
        self._spool_failing = False  # a spool write failed and no write has worked since (log once)
        self._delivered = DeliveredValues()  # what this Sparkplug connection sent: replay skips it
        # Sparkplug
        self._sparkplug = "sparkplug" in settings.formats
        self._bdseq = BdSeqCounter(store)
        self._node = SparkplugNode(settings.group_id, settings.edge_node_id, AliasMap(store), clock)
        self._host = PrimaryHost(settings.primary_host_id) if settings.primary_host_id else None
        self._spb: MqttConnection | None = None
        self._spb_session = 0  # bumps on every connect/disconnect, so stale async steps can tell
        self._subscribed = False
        self._rebirth_handle: asyncio.TimerHandle | None = None
        self._last_rebirth = -1e9
        # JSON
        self._topics = JsonTopics(settings.json_prefix) if "json" in settings.formats else None
        self._json: MqttConnection | None = None
        self._json_online: dict[str, bool] = {}
        self._json_state: dict[str, dict[str, Sample]] = {}

    # -- lifecycle -----------------------------------------------------------------------------------

    async def start(self) -> None:
        """Start connecting (returns at once; births follow the connection). See wait_ready()."""
        self._stopping = False
        if self._sparkplug and self._spb is None:
            self._spb = MqttConnection(self.settings, self.settings.client_id,
                                       before_connect=self._spb_will, on_connected=self._spb_connected,
                                       on_disconnected=self._spb_disconnected, on_message=self._spb_message)
            self._spb.start()
        if self._topics is not None and self._json is None:
            json_id = f"{self.settings.client_id}-json" if self._sparkplug else self.settings.client_id
            self._json = MqttConnection(self.settings, json_id, before_connect=self._json_will,
                                        on_connected=self._json_connected,
                                        on_disconnected=self._json_disconnected,
                                        on_message=self._json_message)
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
        spb_ok = not self._sparkplug or self._node.born
        json_ok = self._json is None or self._json.connected
        return self.connected and spb_ok and json_ok

    @property
    def session_state(self) -> str:
        """Sparkplug session: disconnected, subscribing, waiting_for_host, rebirthing or born."""
        conn = self._spb
        if conn is None or not conn.connected:
            return "disconnected"
        if self._node.holding:
            return "rebirthing"
        if self._node.born:
            return "born"
        return "subscribing" if not self._subscribed else "waiting_for_host"

    def drop_connections(self) -> None:
        """Close the sockets without DISCONNECT, as a crash or cable pull would (tests, chaos drills)."""
        for conn in (self._spb, self._json):
            if conn is not None:
                conn.drop_socket()

    @property
    def connected(self) -> bool:
        conns = [c for c in (self._spb, self._json) if c is not None]
        return bool(conns) and all(c.connected for c in conns)

    async def stop(self) -> None:
        """DDEATH every online device, NDEATH, DISCONNECT (MQTT 5: reason 0x04); JSON: offline, retained."""
        self._stopping = True
        self._cancel_rebirth()
        for fmt in FORMATS:
            await self._settle(fmt, self._conn(fmt))
        spb, self._spb = self._spb, None
        if spb is not None:
            await self._stop_sparkplug(spb)
        conn, self._json = self._json, None
        if conn is not None and self._topics is not None:
            last: Outgoing | None = None
            if conn.connected:
                for device_id, online in self._json_online.items():
                    if online:
                        self._send_json(conn, self._topics.machine_status(device_id, False))
                last = self._topics.gateway_offline()
            await self._confirm_then_disconnect(conn, last, with_will=False)
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        for fmt in FORMATS:
            self._spool_outbox(fmt)

    async def _settle(self, fmt: Format, conn: MqttConnection | None) -> None:
        """Before a clean stop: confirm the outbox with one barrier, or spool what it holds."""
        outbox = self._outbox[fmt]
        if not len(outbox):
            return
        if conn is not None and conn.connected and not self._suspect[fmt]:
            mark = outbox.mark()
            if await self._barrier(fmt, conn, drop_on_timeout=False):
                outbox.confirm(mark)
                return
        self._spool_outbox(fmt)

    async def _stop_sparkplug(self, spb: MqttConnection) -> None:
        last: Outgoing | None = None
        if spb.connected:
            messages = self._node.shutdown()
            if messages:
                last = messages[-1]  # the NDEATH: confirmed before the DISCONNECT
                self._send_spb(messages[:-1], spb)
        else:
            self._node.shutdown()
        await self._confirm_then_disconnect(spb, last, with_will=True)

    async def _confirm_then_disconnect(self, conn: MqttConnection, last: Outgoing | None,
                                       *, with_will: bool) -> None:
        if last is not None:
            await self._publish_final(conn, last)
        await conn.stop(with_will=with_will)

    async def _publish_final(self, conn: MqttConnection, last: Outgoing) -> bool:
        """Publish the last message before a disconnect at QoS 1; True once its PUBACK came."""
        try:
            await conn.publish_confirmed(last.topic, last.payload, qos=1, retain=last.retain, timeout=5.0)
        except MqttUnavailable as exc:
            self._counters["dropped"] += 1
            log.warning("final message not confirmed topic=%s error=%s", last.topic, exc)
            return False
        self._counters["published"] += 1
        return True

    # -- what the collector calls --------------------------------------------------------------------

    def set_node_metrics(self, samples: Sequence[Sample]) -> None:
        """Gateway metrics (version, machines connected, overruns, publish counts): NBIRTH, then NDATA."""
        if self._sparkplug:
            self._send_spb(self._node.set_node_metrics(samples))

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec],
                            samples: Sequence[Sample]) -> None:
        """A machine's session is up: DBIRTH with every metric; JSON online + retained state."""
        if self._sparkplug:
            births = self._node.device_online(device_id, specs, samples)
            if self._send_spb(births) and births:
                for born_id, values in self._node.birth_samples(device_id):
                    self._delivered.record(born_id, values)
            if self._node.live:
                self._kick_replay("sparkplug")  # rows this device left in the spool
        if self._topics is not None:
            self._json_online[device_id] = True
            state = self._json_state.setdefault(device_id, {})
            names = {spec.name for spec in specs}
            for name in [n for n in state if n not in names]:
                del state[name]
            for s in samples:
                state[s.name] = s
            conn = self._json
            if conn is not None and conn.connected:
                self._send_json(conn, self._topics.machine_status(device_id, True))
                for s in samples:
                    self._send_json(conn, self._topics.state(device_id, s))

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        """Changed values: DDATA (alias only, the CNC's timestamps); JSON retained state per value."""
        if not samples:
            return
        if self._sparkplug:
            node = self._node
            if self._spb_live(device_id):
                self._send_live("sparkplug", node.device_data(device_id, samples),
                                HeldBatch(device_id, "data", samples))
            else:
                node.device_data(device_id, samples)  # births will carry the latest values
                self._hold("sparkplug", device_id, "data", samples)
        if self._topics is not None:
            state = self._json_state.setdefault(device_id, {})
            for s in samples:
                state[s.name] = s
            if self._json_live():
                topics = self._topics
                self._send_live("json", [topics.state(device_id, s) for s in samples],
                                HeldBatch(device_id, "data", samples))
            else:
                self._hold("json", device_id, "data", samples)

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        """Alarm events (raise/clear, history): DDATA with the CNC occurrence time; JSON event topic."""
        if not events:
            return
        if self._sparkplug:
            if self._spb_live(device_id):
                self._send_live("sparkplug", self._node.device_events(device_id, events),
                                HeldBatch(device_id, "events", events))
            else:
                self._hold("sparkplug", device_id, "events", events)
        if self._topics is not None:
            if self._json_live():
                topics = self._topics
                self._send_live("json", [topics.event(device_id, s) for s in events],
                                HeldBatch(device_id, "events", events))
            else:
                self._hold("json", device_id, "events", events)

    async def device_offline(self, device_id: str) -> None:
        """A machine's session is lost: DDEATH; JSON offline, retained."""
        if self._sparkplug:
            self._send_spb(self._node.device_offline(device_id))
        if self._topics is not None:
            self._json_online[device_id] = False
            conn = self._json
            if conn is not None and conn.connected:
                self._send_json(conn, self._topics.machine_status(device_id, False))

    async def publish_json_reply(self, device_id: str, payload: dict[str, Any] | list[dict[str, Any]],
                                 source: CommandSource) -> None:
        """A command reply: to the MQTT 5 response topic (with correlation data) or `<machine>/cmd/reply`."""
        if self._topics is None or self._json is None:
            self._counters["dropped"] += 1
            log.warning("JSON reply dropped: the json format is disabled device=%s", device_id)
            return
        topic = source.response_topic or self._topics.reply_topic(device_id)
        props = None
        if self.settings.protocol == "5" and source.response_topic and source.correlation_data is not None:
            props = response_properties(source.correlation_data)
        if self._json.publish(topic, encode(payload), qos=1, retain=False, properties=props):
            self._counters["published"] += 1
        else:
            self._counters["dropped"] += 1

    @property
    def counters(self) -> dict[str, int]:
        """Published/dropped messages, commands, rebirths, connects: a snapshot for node metrics and logs."""
        out = {k: 0 for k in ("published", "dropped", "unknown_commands", "rejected_commands",
                              "rebirth_requests", "rebirths", "rebirths_coalesced", "births")}
        out.update(self._counters)
        out["unknown_metrics"] = self._node.unknown_metrics
        out["encode_errors"] = self._node.encode_errors
        out["sparkplug_connects"] = self._spb.connects if self._spb is not None else 0
        out["json_connects"] = self._json.connects if self._json is not None else 0
        out["stale_state_ignored"] = self._host.ignored if self._host is not None else 0
        out["bdseq_persist_failures"] = self._bdseq.persist_failures
        out["replay_duplicates_skipped"] = self._delivered.skipped
        dropped = getattr(self.spool, "dropped", None)
        if isinstance(dropped, int):
            out["samples_dropped"] = dropped
        if isinstance(self.spool, ReplaySpool):
            out["spool_rows"] = self.spool.pending()
        out["unconfirmed_batches"] = sum(len(o) for o in self._outbox.values())
        for key in ("spooled_batches", "replayed_messages", "replayed_rows", "suspect_dead", "probes"):
            out.setdefault(key, 0)
        return out

    @property
    def bdseq(self) -> int | None:
        """The bdSeq of the current (or last) Sparkplug session."""
        return self._node.bdseq

    # -- Sparkplug session ---------------------------------------------------------------------------

    def _spb_will(self, previous_unsent: bool) -> Will:
        """Before every CONNECT (in the connect worker thread): next bdSeq (persisted) in a fresh NDEATH Will."""
        bdseq = self._bdseq.next_for_connect(previous_unsent)
        will = self._node.will(bdseq)
        return Will(will.topic, will.payload, qos=will.qos, retain=will.retain, tag=bdseq)

    def _spb_connected(self, tag: object) -> None:
        assert isinstance(tag, int), "the Sparkplug Will always carries its bdSeq"
        self._spb_session += 1
        self._subscribed = False
        self._suspect["sparkplug"] = False
        self._delivered.connection_lost()
        self._node.session_started(tag)
        if self._host is not None:
            self._host.new_session()
        self._spawn(self._spb_subscribe(self._spb_session))
        if self._spb is not None:
            self._spawn(self._probe_loop("sparkplug", self._spb, self._spb_session))

    async def _spb_subscribe(self, session: int) -> None:
        conn = self._spb
        if conn is None:
            return
        topics = [(self._node.ncmd_topic, 1), (self._node.dcmd_topic_filter, 1)]
        if self._host is not None:
            topics.append((self._host.topic, 1))
        try:
            await conn.subscribe(topics, timeout=self.settings.connect_timeout_s)
        except MqttUnavailable as exc:
            if session == self._spb_session:
                log.error("Sparkplug subscriptions failed, reconnecting error=%s", exc)
                conn.drop_socket()
            return
        if session != self._spb_session:
            return
        self._subscribed = True
        self._maybe_birth()

    def _maybe_birth(self) -> None:
        conn = self._spb
        if conn is None or not conn.connected or not self._subscribed or self._node.born or self._stopping:
            return
        if self._host is not None and not self._host.online:
            log.info("waiting for primary host STATE online host=%s", self._host.host_id)
            return
        self._counters["births"] += 1
        self._send_births()
        self._kick_replay("sparkplug")

    def _births(self) -> list[Outgoing]:
        """NBIRTH and DBIRTHs, the node metrics refreshed first (not live yet: recorded, not sent)."""
        if self.node_metrics_source is not None:
            self._node.set_node_metrics(self.node_metrics_source())
        return self._node.births()

    def _spb_disconnected(self) -> None:
        self._spool_outbox("sparkplug")
        self._spb_session += 1
        self._subscribed = False
        self._cancel_rebirth()
        self._node.session_lost()
        self._delivered.connection_lost()

    def _spb_message(self, msg: InboundMessage) -> None:
        if self._host is not None and msg.topic == self._host.topic:
            self._state_message(msg)
            return
        for event in self._node.parse_command(msg.topic, msg.payload):
            if isinstance(event, RebirthRequested):
                self._rebirth_requested()
            elif isinstance(event, DeviceCommand):
                self._dispatch_device_command(event, msg)
            elif isinstance(event, CommandIgnored):
                self._counters["unknown_commands" if event.unknown else "rejected_commands"] += 1
                log.warning("Sparkplug command ignored topic=%s reason=%s", msg.topic, event.reason)
                refused = self.on_device_command_refused
                if refused is not None and event.device_id is not None and event.code is not None:
                    refused(event.device_id, event.metric, event.code, event.reason,
                            CommandSource("sparkplug", msg.topic))

    def _state_message(self, msg: InboundMessage) -> None:
        assert self._host is not None
        verdict = self._host.on_state(msg.topic, msg.payload)
        if verdict is StateVerdict.ONLINE:
            self._maybe_birth()
        elif verdict is StateVerdict.OFFLINE and self._node.born and not self._stopping:
            self._spawn(self._primary_host_offline())

    async def _primary_host_offline(self) -> None:
        """§1.3: NDEATH at once, DISCONNECT, then connect again (new bdSeq) and wait for STATE online."""
        conn = self._spb
        if conn is None:
            return
        log.warning("primary host offline: NDEATH and reconnect host=%s",
                    self._host.host_id if self._host else None)
        await self._settle("sparkplug", conn)
        ndeath = self._node.ndeath()
        self._node.session_lost()
        self._cancel_rebirth()
        mark = self._outbox["sparkplug"].mark()  # no live data after this: the node is not live
        sent = None if self._suspect["sparkplug"] else self._delivered.mark()
        if await self._publish_final(conn, ndeath) and sent is not None:
            self._outbox["sparkplug"].confirm(mark)  # the NDEATH's PUBACK proves the data before it arrived
            self._delivered.proven(sent)
        await conn.stop(with_will=True)
        if not self._stopping and self._spb is conn:
            conn.start()

    def _rebirth_requested(self) -> None:
        """NCMD Node Control/Rebirth: stop DATA now; births at once, then at most once per interval."""
        self._counters["rebirth_requests"] += 1
        if self._rebirth_handle is not None:
            self._counters["rebirths_coalesced"] += 1
            return
        if not self._node.request_rebirth():
            return  # not born yet: the session's own births are still to come
        delay = max(0.0, self._last_rebirth + self.settings.rebirth_min_interval_s - time.monotonic())
        self._rebirth_handle = asyncio.get_running_loop().call_later(delay, self._rebirth)

    def _rebirth(self) -> None:
        self._rebirth_handle = None
        if not self._node.born:
            return
        self._last_rebirth = time.monotonic()
        self._counters["rebirths"] += 1
        self._send_births()
        self._kick_replay("sparkplug")

    def _send_births(self) -> None:
        """NBIRTH and the DBIRTHs; what they carry is recorded so the replay does not repeat it."""
        carried = self._node.birth_samples()
        if self._send_spb(self._births()):
            for device_id, samples in carried:
                self._delivered.record(device_id, samples)

    def _cancel_rebirth(self) -> None:
        if self._rebirth_handle is not None:
            self._rebirth_handle.cancel()
            self._rebirth_handle = None

    def _dispatch_device_command(self, event: DeviceCommand, msg: InboundMessage) -> None:
        handler = self.on_device_command
        if handler is None:
            self._counters["rejected_commands"] += 1
            log.warning("DCMD ignored: no command handler device=%s metric=%s", event.device_id,
                        event.metric_name)
            return
        source = CommandSource("sparkplug", msg.topic)
        self._spawn(_await(handler(event.device_id, event.metric_name, event.value, source)))

    def _send_spb(self, messages: Sequence[Outgoing], conn: MqttConnection | None = None) -> bool:
        conn = conn or self._spb
        ok = True
        for m in messages:
            if conn is not None and conn.publish(m.topic, m.payload, m.qos, m.retain):
                self._counters["published"] += 1
            else:
                self._counters["dropped"] += 1
                ok = False
        return ok

    # -- JSON session --------------------------------------------------------------------------------

    def _json_will(self, previous_unsent: bool) -> Will:
        assert self._topics is not None
        m = self._topics.gateway_offline()
        return Will(m.topic, m.payload, qos=m.qos, retain=m.retain)

    def _json_connected(self, tag: object) -> None:
        conn, topics = self._json, self._topics
        if conn is None or topics is None:
            return
        self._json_session += 1
        self._suspect["json"] = False
        # A broker restart may have lost retained messages: state them all again.
        self._send_json(conn, topics.gateway_online())
        for device_id, online in self._json_online.items():
            self._send_json(conn, topics.machine_status(device_id, online))
            for s in self._json_state.get(device_id, {}).values():
                self._send_json(conn, topics.state(device_id, s))
        self._spawn(self._json_subscribe(conn))
        self._spawn(self._probe_loop("json", conn, self._json_session))
        self._kick_replay("json")

    async def _json_subscribe(self, conn: MqttConnection) -> None:
        assert self._topics is not None
        try:
            await conn.subscribe([(self._topics.command_filter, 1)], timeout=self.settings.connect_timeout_s)
        except MqttUnavailable as exc:
            log.error("JSON command subscription failed, reconnecting error=%s", exc)
            conn.drop_socket()

    def _json_disconnected(self) -> None:
        self._json_session += 1
        self._spool_outbox("json")

    def _json_message(self, msg: InboundMessage) -> None:
        assert self._topics is not None
        machine = self._topics.command_machine(msg.topic)
        if machine is None:
            return
        handler = self.on_json_command
        if handler is None:
            self._counters["rejected_commands"] += 1
            log.warning("JSON command ignored: no command handler topic=%s", msg.topic)
            return
        source = CommandSource("json", msg.topic, msg.response_topic, msg.correlation_data)
        self._spawn(_await(handler(machine, msg.payload, source)))

    def _send_json(self, conn: MqttConnection, m: Outgoing) -> bool:
        if conn.publish(m.topic, m.payload, m.qos, m.retain):
            self._counters["published"] += 1
            return True
        self._counters["dropped"] += 1
        return False

    # -- store and forward ---------------------------------------------------------------------------

    def _spb_live(self, device_id: str) -> bool:
        """Sparkplug DATA for this device can go out live now."""
        conn = self._spb
        return (conn is not None and conn.connected and self._node.live and self._node.is_online(device_id)
                and not self._suspect["sparkplug"])

    def _json_live(self) -> bool:
        conn = self._json
        return conn is not None and conn.connected and not self._suspect["json"]

    def _conn(self, fmt: Format) -> MqttConnection | None:
        return self._spb if fmt == "sparkplug" else self._json

    def _session(self, fmt: Format) -> int:
        return self._spb_session if fmt == "sparkplug" else self._json_session

    def _send_live(self, fmt: Format, messages: Sequence[Outgoing], batch: HeldBatch) -> None:
        """Publish live messages; remember the batch until a barrier confirms it, or spool it on failure."""
        if not messages:
            return
        conn = self._conn(fmt)
        if conn is None:
            self._hold(fmt, batch.device_id, batch.kind, batch.samples)
            return
        sent = self._send_spb(messages, conn) if fmt == "sparkplug" else \
            all([self._send_json(conn, m) for m in messages])
        self._outbox[fmt].record(batch)
        if not sent:
            self._suspect_dead(fmt, conn, "publish refused by the MQTT client")

    def _hold(self, fmt: Format, device_id: str, kind: str, samples: Sequence[Sample]) -> None:
        """Spool samples that cannot go live, after any older unconfirmed ones (keeps the order)."""
        self._spool_outbox(fmt)
        self._spool_batch(fmt, HeldBatch(device_id, kind, samples))

    def _spool_batch(self, fmt: Format, batch: HeldBatch) -> None:
        kind: SampleKind = "events" if batch.kind == "events" else "data"
        try:
            self.spool.hold(fmt, batch.device_id, kind, batch.samples)
        except Exception as exc:  # a broken spool must not take the publisher down
            self._counters["spool_errors"] += 1
            self._counters["spool_error_samples"] += len(batch.samples)
            if not self._spool_failing:
                log.error("spool write failed, samples lost until a write works again (counted in "
                          "spool_error_samples) format=%s device=%s samples=%d error=%s", fmt,
                          batch.device_id, len(batch.samples), exc)
            self._spool_failing = True
            return
        if self._spool_failing:
            log.warning("spool writes work again, lost samples=%d", self._counters["spool_error_samples"])
        self._spool_failing = False
        self._counters["spooled_batches"] += 1

    def _spool_outbox(self, fmt: Format) -> None:
        """Unconfirmed live batches to the spool; they went out, so a replay on this connection skips them."""
        for batch in self._outbox[fmt].take_all():
            if fmt == "sparkplug":
                self._delivered.record(batch.device_id, batch.samples)
            self._spool_batch(fmt, batch)

    def _suspect_dead(self, fmt: Format, conn: MqttConnection, reason: str, drop: bool = True) -> None:
        """No proof of delivery: spool from now on, keep the unconfirmed, and force a reconnect."""
        if not self._suspect[fmt]:
            self._counters["suspect_dead"] += 1
            log.warning("MQTT connection suspected dead, spooling format=%s reason=%s", fmt, reason)
        self._suspect[fmt] = True
        self._spool_outbox(fmt)
        if drop and conn.connected:
            conn.drop_socket()

    def _probe_topic(self, fmt: Format) -> str:
        client_id = self.settings.client_id
        if fmt == "json" and self._sparkplug:
            client_id = f"{client_id}-json"
        return f"{PROBE_PREFIX}/{client_id}"

    async def _barrier(self, fmt: Format, conn: MqttConnection, *, drop_on_timeout: bool = True) -> bool:
        """Publish a QoS 1 probe and wait for its PUBACK: True means all sent before it arrived."""
        self._counters["probes"] += 1
        sent = None if self._suspect[fmt] else self._delivered.mark()
        try:
            await conn.publish_confirmed(self._probe_topic(fmt), b"", qos=1, retain=False,
                                         timeout=self.forwarding.probe_timeout_s)
        except MqttUnavailable as exc:
            self._suspect_dead(fmt, conn, str(exc), drop=drop_on_timeout)
            return False
        if fmt == "sparkplug" and sent is not None:
            self._delivered.proven(sent)
        return True

    async def _probe_loop(self, fmt: Format, conn: MqttConnection, session: int) -> None:
        """Confirm live batches every probe interval while this connection session lasts."""
        outbox = self._outbox[fmt]
        while True:
            await asyncio.sleep(self.forwarding.probe_interval_s)
            if session != self._session(fmt) or self._suspect[fmt] or not conn.connected:
                return
            self._drain_waiting_rows(fmt)
            if not len(outbox):
                continue
            mark = outbox.mark()
            if not await self._barrier(fmt, conn):
                return
            outbox.confirm(mark)

    def _drain_waiting_rows(self, fmt: Format) -> None:
        """Rows still waiting with no replay running (a replay that failed, a spool that had no room to
        delete): replay them now, not at the next reconnect."""
        spool = self.spool
        if self._replaying[fmt] or not isinstance(spool, ReplaySpool) or (fmt == "sparkplug" and
                                                                          not self._node.live):
            return
        if spool.pending(fmt):
            self._kick_replay(fmt)

    def _kick_replay(self, fmt: Format) -> None:
        """Start replaying the spool for `fmt` (or make the running replay look again)."""
        if self._stopping or not isinstance(self.spool, ReplaySpool):
            return
        if self._replaying[fmt]:
            self._replay_again[fmt] = True
            return
        conn = self._conn(fmt)
        if conn is None:
            return
        self._replaying[fmt] = True
        self._replay_again[fmt] = False
        self._spawn(self._replay(fmt, conn, self._session(fmt)))

    async def _replay(self, fmt: Format, conn: MqttConnection, session: int) -> None:
        try:
            await self._replay_rows(fmt, conn, session)
        except Exception as exc:  # the spool failed: the rows stay and the probe loop kicks a new replay
            self._counters["replay_errors"] += 1
            log.error("spool replay failed, retried within a probe interval format=%s error=%s", fmt, exc)
        finally:
            self._replaying[fmt] = False

    async def _replay_rows(self, fmt: Format, conn: MqttConnection, session: int) -> None:
        """Oldest first, paced, each row as its own historical message(s); rows acked after a barrier."""
        spool = self.spool
        assert isinstance(spool, ReplaySpool)
        pause = 1.0 / self.forwarding.replay_rows_per_s
        started = time.monotonic()
        sent_rows = 0

        def current() -> bool:
            return (session == self._session(fmt) and conn.connected and not self._suspect[fmt]
                    and not self._stopping and (fmt == "json" or self._node.live))

        while current():
            devices = [d for d in self._node.device_ids() if self._node.is_online(d)] \
                if fmt == "sparkplug" else None
            entries = spool.oldest(fmt, self.forwarding.replay_batch, devices)
            if not entries:
                if self._replay_again[fmt]:
                    self._replay_again[fmt] = False
                    continue
                break
            done: list[int] = []
            for entry in entries:
                if fmt == "sparkplug" and not self._node.is_online(entry.device_id):
                    continue  # went offline since the query: its rows wait for its next DBIRTH
                done.append(entry.id)
                samples = self._delivered.fresh(entry.device_id, entry.samples) if fmt == "sparkplug" \
                    else entry.samples
                messages = self._historical_messages(fmt, entry, samples)
                for m in messages:
                    if not current():
                        return
                    sent = self._send_spb([m], conn) if fmt == "sparkplug" else self._send_json(conn, m)
                    if not sent:
                        self._suspect_dead(fmt, conn, "replay publish refused by the MQTT client")
                        return
                    self._counters["replayed_messages"] += 1
                if fmt == "sparkplug" and messages:
                    self._delivered.record(entry.device_id, samples)
                await asyncio.sleep(pause)  # per row: a tick's worth of one machine
            if not current() or not await self._barrier(fmt, conn):
                return
            spool.ack(done)
            if fmt == "sparkplug":
                acked = set(done)
                for entry in entries:
                    if entry.id in acked:
                        self._delivered.discard(entry.device_id, entry.samples)
            self._counters["replayed_rows"] += len(done)
            sent_rows += len(done)
        left = spool.pending(fmt)
        if fmt == "sparkplug" and not left:
            self._delivered.forget()
        if sent_rows:
            log.info("spool replayed format=%s rows=%d seconds=%.1f left=%d", fmt, sent_rows,
                     time.monotonic() - started, left)

    def _historical_messages(self, fmt: Format, entry: Any, samples: Sequence[Sample]) -> list[Outgoing]:
        if not samples:
            return []
        samples = [s if s.historical else replace(s, historical=True) for s in samples]
        if fmt == "sparkplug":
            return self._node.historical_data(entry.device_id, samples)
        topics = self._topics
        if topics is None:
            return []
        if entry.kind == "events":
            return [topics.event(entry.device_id, s, entry.id) for s in samples]
        return [topics.history(entry.device_id, s, entry.id) for s in samples]

    # -- tasks ---------------------------------------------------------------------------------------

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._task_done)

    def _task_done(self, task: asyncio.Task[None]) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            log.error("publisher task failed", exc_info=task.exception())


async def _await(awaitable: Awaitable[None]) -> None:
    await awaitable
