"""The plain JSON topics over their own MQTT connection (docs/topics.md; names and bodies: json_topics).

Its Will is the retained gateway "offline", so a Sparkplug reconnect never disturbs JSON subscribers. The
last state of every machine is kept here and stated again (retained) on every connect, since a broker
restart may have lost retained messages. When a machine's session drops, its retained state is restated
with quality STALE (Sparkplug's DDEATH says the same to Sparkplug hosts); its next session states it GOOD.
Live state goes out at QoS 0 through the link (edge.publish.link);
what cannot go live is held and replayed as `history` / `events` messages.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence
from typing import Any

from edge.publish.forwarding import ForwardingPolicy
from edge.publish.holding import SpoolWriter
from edge.publish.identity import IdentityGuard
from edge.publish.inbound import CommandHandlers, CommandSource
from edge.publish.json_topics import JsonTopics, encode
from edge.publish.link import DeliveryLink
from edge.publish.mqtt import InboundMessage, MqttConnection, MqttUnavailable, Will, response_properties
from edge.publish.node import Outgoing, now_ms
from edge.publish.replay import Replayer
from edge.publish.settings import PublishSettings
from edge.publish.tasks import BackgroundTasks, awaited
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)


class JsonSession:
    """The JSON topics: machine status and state (retained), events, commands and their replies."""

    def __init__(self, settings: PublishSettings, *, beside_sparkplug: bool, writer: SpoolWriter,
                 policy: ForwardingPolicy, counters: Counter[str], tasks: BackgroundTasks,
                 handlers: CommandHandlers, guard: IdentityGuard) -> None:
        self.settings = settings
        self._guard = guard  # a taken-over client id is the same conflict as the Sparkplug one's
        self.topics = JsonTopics(settings.json_prefix)
        self._beside_sparkplug = beside_sparkplug  # then its client id is `<client_id>-json`
        self._counters = counters
        self._tasks = tasks
        self._handlers = handlers
        self.link = DeliveryLink("json", writer, counters, policy, tasks)
        self.replay = Replayer(self.link, self, writer.spool, counters, tasks)
        self._online: dict[str, bool] = {}
        self._offline_since: dict[str, int] = {}  # epoch ms each offline machine's session dropped
        self._state: dict[str, dict[str, Sample]] = {}

    # -- lifecycle -----------------------------------------------------------------------------------

    def start(self) -> None:
        if self.link.conn is None:
            client_id = self.settings.client_id
            if self._beside_sparkplug:
                client_id = f"{client_id}-json"
            guard = self._guard
            conn = MqttConnection(self.settings, client_id, before_connect=self._will,
                                  on_connected=self._connected, on_disconnected=self._disconnected,
                                  on_message=self.handle_message,
                                  on_lost=lambda lasted, reason: guard.session_lost(client_id, lasted, reason),
                                  min_delay=guard.reconnect_floor_s)
            self.link.attach(conn, client_id)
            conn.start()

    async def stop(self) -> None:
        """Every online machine offline and the gateway offline (retained, confirmed), then DISCONNECT."""
        conn = self.link.detach()
        if conn is None:
            return
        last: Outgoing | None = None
        if conn.connected:
            for device_id, online in self._online.items():
                if online:
                    self._send(conn, self.topics.machine_status(device_id, False))
                    self._send_stale(conn, device_id, now_ms())
            last = self.topics.gateway_offline()
        await self.link.confirm_then_disconnect(conn, last, with_will=False)

    # -- what the publisher fans out -----------------------------------------------------------------

    def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        self._online[device_id] = True
        self._offline_since.pop(device_id, None)
        state = self._state.setdefault(device_id, {})
        names = {spec.name for spec in specs}
        for name in [n for n in state if n not in names]:
            del state[name]
        for s in samples:
            state[s.name] = s
        conn = self.link.conn
        if conn is not None and conn.connected:
            self._send(conn, self.topics.machine_status(device_id, True))
            for s in samples:
                self._send(conn, self.topics.state(device_id, s))

    def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        state = self._state.setdefault(device_id, {})
        for s in samples:
            state[s.name] = s
        link = self.link
        if link.live:
            topics = self.topics
            link.send_live([topics.state(device_id, s) for s in samples], device_id, "data", samples)
        else:
            link.hold(device_id, "data", samples)

    def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        link = self.link
        if link.live:
            topics = self.topics
            link.send_live([topics.event(device_id, s) for s in events], device_id, "events", events)
        else:
            link.hold(device_id, "events", events)

    def device_offline(self, device_id: str) -> None:
        self._online[device_id] = False
        self._offline_since[device_id] = since = now_ms()
        conn = self.link.conn
        if conn is not None and conn.connected:
            self._send(conn, self.topics.machine_status(device_id, False))
            self._send_stale(conn, device_id, since)

    def _send_stale(self, conn: MqttConnection, device_id: str, since_ms: int) -> None:
        """Restate a machine's retained values with quality STALE (its session is down since `since_ms`)."""
        topics = self.topics
        for s in self._state.get(device_id, {}).values():
            self._send(conn, topics.state(device_id, s, since_ms))

    def reply(self, conn: MqttConnection, device_id: str, payload: dict[str, Any] | list[dict[str, Any]],
              source: CommandSource) -> None:
        """A command reply: to the MQTT 5 response topic (with correlation data) or `<machine>/cmd/reply`."""
        topic = source.response_topic or self.topics.reply_topic(device_id)
        props = None
        if self.settings.protocol == "5" and source.response_topic and source.correlation_data is not None:
            props = response_properties(source.correlation_data)
        if conn.publish(topic, encode(payload), qos=1, retain=False, properties=props):
            self._counters["published"] += 1
        else:
            self._counters["dropped"] += 1

    # -- the MQTT session ----------------------------------------------------------------------------

    def _will(self, previous_unsent: bool) -> Will:
        m = self.topics.gateway_offline()
        return Will(m.topic, m.payload, qos=m.qos, retain=m.retain)

    def _connected(self, tag: object) -> None:
        conn, topics = self.link.conn, self.topics
        if conn is None:
            return
        self.link.connection_up()
        # A broker restart may have lost retained messages: state them all again.
        self._send(conn, topics.gateway_online())
        for device_id, online in self._online.items():
            self._send(conn, topics.machine_status(device_id, online))
            if not online:
                self._send_stale(conn, device_id, self._offline_since.get(device_id) or now_ms())
                continue
            for s in self._state.get(device_id, {}).values():
                self._send(conn, topics.state(device_id, s))
        self._tasks.spawn(self._subscribe(conn))
        self.link.start_probing(self.replay.drain_waiting_rows)
        self.replay.kick()

    async def _subscribe(self, conn: MqttConnection) -> None:
        try:
            await conn.subscribe([(self.topics.command_filter, 1)], timeout=self.settings.connect_timeout_s)
        except MqttUnavailable as exc:
            log.error("JSON command subscription failed, reconnecting error=%s", exc)
            conn.drop_socket()

    def _disconnected(self) -> None:
        self.link.connection_down()

    def handle_message(self, msg: InboundMessage) -> None:
        machine = self.topics.command_machine(msg.topic)
        if machine is None:
            return
        handler = self._handlers.json
        if handler is None:
            self._counters["rejected_commands"] += 1
            log.warning("JSON command ignored: no command handler topic=%s", msg.topic)
            return
        source = CommandSource("json", msg.topic, msg.response_topic, msg.correlation_data)
        self._tasks.spawn(awaited(handler(machine, msg.payload, source)))

    def _send(self, conn: MqttConnection, m: Outgoing) -> bool:
        return self.link.send(conn, (m,))

    # -- what the replay asks (edge.publish.replay.ReplayTarget) -------------------------------------

    def replay_ready(self) -> bool:
        return True

    def replay_devices(self) -> list[str] | None:
        return None

    def replay_accepts(self, device_id: str) -> bool:
        return True

    def historical(self, entry: Any, samples: Sequence[Sample]) -> list[Outgoing]:
        if entry.kind == "events":
            return [self.topics.event(entry.device_id, s, entry.id) for s in samples]
        return [self.topics.history(entry.device_id, s, entry.id) for s in samples]
