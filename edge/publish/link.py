"""One MQTT connection's proof of delivery: live or suspect, the outbox, the QoS 1 barrier and its probe loop.

Store and forward (docs/reliability.md): live DATA is QoS 0, so each connection keeps an outbox of live
batches until a QoS 1 probe's PUBACK confirms them (edge.publish.forwarding). A probe without PUBACK in
time, a failed publish or a lost connection makes the connection *suspect*: unconfirmed and new samples go
to the spool, the socket is dropped, and after the reconnect (and, for Sparkplug, the births) the spool is
replayed (edge.publish.replay).

Each session (Sparkplug, JSON) owns one `DeliveryLink` and sends its messages through it (command replies
aside), so the outbox, the suspect flag and the connection-session number have one writer per connection.
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from collections.abc import Callable, Sequence

from edge.publish.forwarding import ForwardingPolicy, HeldBatch, Outbox
from edge.publish.holding import Format, SpoolWriter
from edge.publish.mqtt import MqttConnection, MqttUnavailable
from edge.publish.node import Outgoing
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.tasks import BackgroundTasks
from edge.samples import Sample

log = logging.getLogger(__name__)

PROBE_PREFIX = "focas-edge/probe"  # QoS 1 delivery barriers: <prefix>/<client id>, empty, not retained


class DeliveryLink:
    """What one connection has sent without proof, and whether it can still be trusted to deliver."""

    def __init__(self, fmt: Format, writer: SpoolWriter, counters: Counter[str], policy: ForwardingPolicy,
                 tasks: BackgroundTasks, delivered: DeliveredValues | None = None) -> None:
        self.fmt = fmt
        self.policy = policy
        self._writer = writer
        self._counters = counters
        self._tasks = tasks
        # Sparkplug only: what went out on this connection, so the replay skips what the host has.
        self._delivered = delivered
        self.conn: MqttConnection | None = None
        self.probe_topic = PROBE_PREFIX
        self.session = 0  # bumps on every connect/disconnect, so stale async steps can tell
        self.suspect = False
        self.outbox = Outbox()

    def attach(self, conn: MqttConnection, client_id: str) -> None:
        """The connection this link proves delivery on (probes go to a topic named by its client id)."""
        self.conn = conn
        self.probe_topic = f"{PROBE_PREFIX}/{client_id}"

    def detach(self) -> MqttConnection | None:
        conn, self.conn = self.conn, None
        return conn

    @property
    def live(self) -> bool:
        """Connected and not suspect: live messages may go out."""
        conn = self.conn
        return conn is not None and conn.connected and not self.suspect

    def connection_up(self) -> None:
        self.session += 1
        self.suspect = False

    def connection_down(self) -> None:
        self.session += 1
        self.spool_outbox()

    # -- sending ---------------------------------------------------------------------------------------

    def send(self, conn: MqttConnection | None, messages: Sequence[Outgoing]) -> bool:
        """Hand messages to paho; False if any was refused (all are tried, each counted)."""
        ok = True
        for m in messages:
            if conn is not None and conn.publish(m.topic, m.payload, m.qos, m.retain):
                self._counters["published"] += 1
            else:
                self._counters["dropped"] += 1
                ok = False
        return ok

    def send_live(self, messages: Sequence[Outgoing], device_id: str, kind: str, samples: Sequence[Sample]) -> None:
        """Publish live messages; remember their batch (one device's samples of one kind) until a barrier
        confirms it, or spool it on failure."""
        if not messages:
            return
        conn = self.conn
        if conn is None:
            self.hold(device_id, kind, samples)
            return
        sent = self.send(conn, messages)
        self.outbox.add(device_id, kind, samples)
        if not sent:
            self.suspect_dead(conn, "publish refused by the MQTT client")

    async def publish_final(self, conn: MqttConnection, last: Outgoing) -> bool:
        """Publish the last message before a disconnect at QoS 1; True once its PUBACK came."""
        try:
            await conn.publish_confirmed(last.topic, last.payload, qos=1, retain=last.retain, timeout=5.0)
        except MqttUnavailable as exc:
            self._counters["dropped"] += 1
            log.warning("final message not confirmed topic=%s error=%s", last.topic, exc)
            return False
        self._counters["published"] += 1
        return True

    async def confirm_then_disconnect(self, conn: MqttConnection, last: Outgoing | None,
                                      *, with_will: bool) -> None:
        if last is not None:
            await self.publish_final(conn, last)
        await conn.stop(with_will=with_will)

    # -- holding ---------------------------------------------------------------------------------------

    def hold(self, device_id: str, kind: str, samples: Sequence[Sample]) -> None:
        """Spool samples that cannot go live, after any older unconfirmed ones (keeps the order)."""
        self.spool_outbox()
        self._writer.write(self.fmt, HeldBatch(device_id, kind, samples))

    def spool_outbox(self) -> None:
        """Unconfirmed live batches to the spool; they went out, so a replay on this connection skips them."""
        for batch in self.outbox.take_all():
            if self._delivered is not None:
                self._delivered.record(batch.device_id, batch.samples)
            self._writer.write(self.fmt, batch)

    def suspect_dead(self, conn: MqttConnection, reason: str, drop: bool = True) -> None:
        """No proof of delivery: spool from now on, keep the unconfirmed, and force a reconnect."""
        if not self.suspect:
            self._counters["suspect_dead"] += 1
            log.warning("MQTT connection suspected dead, spooling format=%s reason=%s", self.fmt, reason)
        self.suspect = True
        self.spool_outbox()
        if drop and conn.connected:
            conn.drop_socket()

    # -- the barrier -----------------------------------------------------------------------------------

    async def barrier(self, conn: MqttConnection, *, drop_on_timeout: bool = True) -> bool:
        """Publish a QoS 1 probe and wait for its PUBACK: True means all sent before it arrived."""
        self._counters["probes"] += 1
        delivered = self._delivered
        sent = None if self.suspect or delivered is None else delivered.mark()
        try:
            await conn.publish_confirmed(self.probe_topic, b"", qos=1, retain=False,
                                         timeout=self.policy.probe_timeout_s)
        except MqttUnavailable as exc:
            self.suspect_dead(conn, str(exc), drop=drop_on_timeout)
            return False
        if delivered is not None and sent is not None:
            delivered.proven(sent)
        return True

    async def settle(self) -> None:
        """Before a clean stop: confirm the outbox with one barrier, or spool what it holds."""
        outbox = self.outbox
        if not len(outbox):
            return
        conn = self.conn
        if conn is not None and conn.connected and not self.suspect:
            mark = outbox.mark()
            if await self.barrier(conn, drop_on_timeout=False):
                outbox.confirm(mark)
                return
        self.spool_outbox()

    def start_probing(self, each_round: Callable[[], None]) -> None:
        """Confirm live batches every probe interval while the current connection session lasts;
        `each_round` runs first in every round (the replay looks for rows left waiting)."""
        if self.conn is not None:
            self._tasks.spawn(self._probe_loop(self.conn, self.session, each_round))

    async def _probe_loop(self, conn: MqttConnection, session: int, each_round: Callable[[], None]) -> None:
        outbox = self.outbox
        while True:
            await asyncio.sleep(self.policy.probe_interval_s)
            if session != self.session or self.suspect or not conn.connected:
                return
            each_round()
            if not len(outbox):
                continue
            mark = outbox.mark()
            if not await self.barrier(conn):
                return
            outbox.confirm(mark)
