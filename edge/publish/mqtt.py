"""One MQTT connection (paho-mqtt 2.x) driven by the asyncio event loop: no network thread.

What this adds to paho:
- paho's socket is watched by the event loop (add_reader; writes flushed once per loop turn, add_writer
  only while the kernel buffer is full), so a publish costs no thread hand-off, no socketpair wake-up and
  no lock contention: every message published during one loop turn goes out in one flush. Only the
  blocking part of a connect attempt (TCP connect, TLS handshake) runs in a worker thread;
- a fresh Will before *every* CONNECT, reconnects included (`before_connect`, from paho's
  on_pre_connect), which is how Sparkplug's bdSeq advances;
- clean session (3.1.1) / clean start with session expiry 0 (5) on every attempt: paho's MQTT 5 default,
  clean start on the first connect only, would break Sparkplug on reconnect;
- reconnect delays that grow exponentially to a cap, each drawn with jitter so a fleet does not reconnect in
  lock-step after a broker restart, never shorter than `min_delay()` (an identity conflict backs off). While
  nobody listens at the broker's port (refused, unreachable: the broker never sees such an attempt) the
  delay is capped at `reconnect_probe_s` (0.5 s, jittered), so a broker back from an outage is reached within
  a second, not after a backoff grown to `reconnect_max_s`. While the address accepts and does not serve
  (closed before CONNACK, CONNACK "server unavailable/busy": a proxy in front of a broker that is down) it is
  capped at `reconnect_not_serving_s` (2 s, drawn in [1, 2] s: at most one attempt a second). A broker that
  rejects the attempt on its merits (credentials, TLS) keeps the growing backoff;
- `on_lost(lasted_s, reason)` for a session the broker ended and we did not, told at the next CONNACK and
  only when that came at the first attempt: a broker that ends a session and takes the client straight back
  is what a taken-over client id looks like, a broker restart or a network loss is not (edge.publish.identity);
- keepalive (PINGREQ, and a dead-broker verdict when no PINGRESP comes) from a once-a-second loop timer;
- awaitable SUBACK / PUBACK;
- QoS 0 messages without properties (all Sparkplug DATA) are encoded here (edge.publish.mqtt_wire) and
  every such message of one loop turn is handed to paho as one write: paho's own publish costs ~7 us and
  one send() per message. The batch enters paho's queue before any packet paho queues itself, so wire
  order is publish order; a batch is never carried over to a new socket;
- nothing of a previous connection is re-sent after a reconnect (the publisher's spool owns redelivery).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import socket
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from edge.publish import connect_failure, mqtt_wire
from edge.publish.broker_trouble import (
    NOT_AUTHORISED,
    Answer,
    BrokerTrouble,
    answer_to_close,
    answer_to_connack,
    answer_to_error,
    is_tls_failure,
)
from edge.publish.credentials import apply_credentials
from edge.publish.settings import PublishSettings

log = logging.getLogger(__name__)

# QoS 0 packets of one loop turn are handed to paho in writes of about this size. paho copies the rest of a
# write after every partial send (`packet[pos:]`), so one write of a whole turn (the 1,000 DBIRTHs after a
# reconnect, a replay's slice: megabytes) was copied again for every send the kernel cut short, and left
# blocks of megabytes to the C allocator (docs/performance.md, "Broker outage at 1,000 machines").
RAW_WRITE_BYTES = 64 * 1024
MISC_INTERVAL_S = 1.0  # keepalive housekeeping (paho's loop_misc); keepalives are whole seconds
CONNECT_TIMEOUT_S = 5.0  # TCP connect + TLS handshake of one attempt


@dataclass(frozen=True, slots=True)
class Will:
    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = False
    tag: object = None  # handed back with on_connected (Sparkplug: the bdSeq this CONNECT carried)


@dataclass(frozen=True, slots=True)
class InboundMessage:
    topic: str
    payload: bytes
    retain: bool
    response_topic: str | None = None  # MQTT 5 request/response
    correlation_data: bytes | None = None


class MqttUnavailable(Exception):
    """The broker did not answer in time or refused (subscribe, confirmed publish)."""


def backoff_delay(attempt: int, minimum: float, maximum: float, rng: random.Random | None = None) -> float:
    """Delay before retry number `attempt` (0-based): min * 2**attempt capped at max, jittered to [d/2, d]."""
    ceiling = min(maximum, minimum * (2 ** min(attempt, 32)))
    return (rng or random).uniform(ceiling / 2, ceiling)


def retry_delay(attempt: int, settings: PublishSettings, answer: Answer,
                rng: random.Random | None = None) -> float:
    """Delay before retry number `attempt`: the backoff, capped (jittered the same way) while the last attempt
    found nobody at the broker's port (`reconnect_probe_s`) or a broker not serving (`reconnect_not_serving_s`,
    and then never under half of it: a refusing broker is not hammered), so the reconnect after an outage
    comes within the cap; an attempt rejected on its merits keeps the backoff."""
    delay = backoff_delay(attempt, settings.reconnect_min_s, settings.reconnect_max_s, rng)
    if answer is Answer.NOBODY:
        probe = min(settings.reconnect_probe_s, settings.reconnect_max_s)
        return min(delay, (rng or random).uniform(probe / 2, probe))
    if answer is Answer.NOT_SERVING:
        cap = min(settings.reconnect_not_serving_s, settings.reconnect_max_s)
        return max(cap / 2, min(delay, (rng or random).uniform(cap / 2, cap)))
    return delay


class MqttConnection:
    """A supervised connection; create and use it on the event loop that drives it."""

    def __init__(self, settings: PublishSettings, client_id: str, *,
                 before_connect: Callable[[bool], Will | None],
                 on_connected: Callable[[object], None],
                 on_disconnected: Callable[[], None],
                 on_message: Callable[[InboundMessage], None],
                 on_lost: Callable[[float, str], None] | None = None,
                 min_delay: Callable[[], float] | None = None) -> None:
        self._settings = settings
        self._client_id = client_id
        self._before_connect = before_connect
        self._on_connected = on_connected
        self._on_disconnected = on_disconnected
        self._on_message = on_message
        self._on_lost = on_lost
        self._min_delay = min_delay
        self._connected_at = 0.0  # loop time of the last CONNACK
        self._dropping = False  # drop_socket() asked for this loss: not the broker's doing
        self._lost: tuple[float, str] | None = None  # (lasted_s, reason) of a session the broker ended
        self._back_at_once = False  # the last CONNACK came at the first attempt after a lost session
        self._v5 = settings.protocol == "5"
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._client: paho.Client | None = None
        self._supervisor: asyncio.Task[None] | None = None
        self._session_over: asyncio.Event | None = None  # set when the current socket is closed
        self._watched: Any = None  # the socket the loop watches (paho's, between connect and close)
        self._writer_added = False
        self._flush_scheduled = False
        self._connecting = False  # a connect attempt runs in a worker thread
        self._misc_handle: asyncio.TimerHandle | None = None
        self._attempt = 0  # failed attempts since the last CONNACK
        self._previous_unsent = False  # the previous attempt failed before CONNECT left
        self._answer = Answer.REJECTED  # what the last failed attempt met (retry_delay); the backoff by default
        self._will_tag: object = None
        self._attempt_error: str | None = None  # paho's first error while this attempt awaits its CONNACK
        self._attempt_reported = False  # this attempt's failure is logged already
        self._pending: dict[int, asyncio.Future[Any]] = {}
        self._batch: list[bytes] = []  # QoS 0 PUBLISH packets of this loop turn, for the watched socket
        self._batch_bytes = 0
        self._room_waiters: list[asyncio.Future[None]] = []  # wait_for_room()
        self._topics = mqtt_wire.TopicCache(v5=self._v5)
        if not mqtt_wire.AVAILABLE:
            log.warning("raw QoS 0 PUBLISH fast path off, paho publishes every message (slower) "
                        "paho_mqtt=%s problem=%s", mqtt_wire.PAHO_VERSION, mqtt_wire.PROBLEM)
        self.connected = False  # CONNACK accepted and not lost since
        self.connects = 0
        self.trouble = BrokerTrouble(settings.host, settings.port, client_id, log)  # outages, summarised

    # -- lifecycle -----------------------------------------------------------------------------------

    def start(self) -> None:
        """Begin connecting in the background; on_connected is called (on the loop) once it succeeds."""
        self._loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        client = self._make_client()
        self._client = client
        s = self._settings
        kwargs: dict[str, Any] = {}
        if self._v5:
            kwargs["clean_start"] = True  # every attempt; session expiry stays 0 (property absent)
        client.connect_async(s.host, s.port, keepalive=s.keepalive, **kwargs)
        self._supervisor = self._loop.create_task(self._supervise(client))

    def _make_client(self) -> paho.Client:
        s = self._settings
        protocol = paho.MQTTv5 if self._v5 else paho.MQTTv311
        kwargs: dict[str, Any] = {} if self._v5 else {"clean_session": True}
        client = paho.Client(CallbackAPIVersion.VERSION2, client_id=self._client_id, protocol=protocol,
                             reconnect_on_failure=False, **kwargs)
        apply_credentials(client, s)
        client.connect_timeout = CONNECT_TIMEOUT_S
        client.on_pre_connect = self._paho_pre_connect
        client.on_connect = self._paho_connect
        client.on_disconnect = self._paho_disconnect
        client.on_message = self._paho_message
        client.on_subscribe = self._paho_subscribe
        # on_publish stays unset while no PUBACK is awaited: paho builds a reason code and a property set
        # for every QoS 0 message it reports, and QoS 0 DATA is nearly all the traffic (see _wait).
        client.on_socket_close = self._paho_socket_close
        return client

    async def stop(self, *, with_will: bool = False, timeout: float = 5.0) -> None:
        """DISCONNECT, close the socket and end the supervisor.

        MQTT 5 `with_will`: reason 0x04 "disconnect with will message", so the broker sends the Will too.
        """
        client, self._client = self._client, None
        if client is None:
            return
        supervisor = self._supervisor
        if self._watched is not None:
            self._queue_batch(client)
            if self._v5 and with_will:
                client.disconnect(reasoncode=ReasonCode(PacketTypes.DISCONNECT, "Disconnect with will message"))
            else:
                client.disconnect()
        elif not self._connecting and supervisor is not None:
            supervisor.cancel()  # waiting out a backoff delay: nothing to close
        if supervisor is not None:
            _, running = await asyncio.wait({supervisor}, timeout=timeout)
            if running:
                log.warning("MQTT connection did not close within %ss client_id=%s", timeout, self._client_id)
                supervisor.cancel()
                await asyncio.wait({supervisor})
        self._close_socket(client)
        self._set_disconnected()
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(MqttUnavailable("connection stopped"))
        self._pending.clear()

    def drop_socket(self) -> None:
        """Close the TCP socket without DISCONNECT (as a crash would): the broker publishes the Will."""
        client = self._client
        sock = client.socket() if client is not None else None
        if isinstance(sock, socket.socket):
            self._dropping = True
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    # -- supervision (event loop) ----------------------------------------------------------------------

    async def _supervise(self, client: paho.Client) -> None:
        """Connect, serve the socket until it closes, wait the backoff delay, again; until stop()."""
        loop = asyncio.get_running_loop()
        while self._client is client:
            self._session_over = asyncio.Event()
            if await self._attempt_connect(loop, client):
                await self._session_over.wait()
            if self._client is not client:
                return
            delay = self._delay()
            self._attempt += 1
            await asyncio.sleep(delay)
            # A conflict may have been found meanwhile (the other connection's loss): ask for the floor now.
            floor = self._min_delay() if self._min_delay is not None else 0.0
            if floor > delay:
                await asyncio.sleep(floor - delay)

    async def _attempt_connect(self, loop: asyncio.AbstractEventLoop, client: paho.Client) -> bool:
        """One attempt: the blocking TCP/TLS connect and the CONNECT packet in a worker thread, then the
        socket is handed to the loop. True when a socket is up (the CONNACK decides the rest)."""
        self._unwatch()
        client.on_socket_register_write = None  # in the worker, paho writes CONNECT itself
        client.on_socket_unregister_write = None
        self._attempt_error = None
        self._attempt_reported = False
        client.on_log = self._paho_log  # until the CONNACK: paho tells its socket errors only there
        self._connecting = True
        self._answer = Answer.REJECTED
        try:
            await loop.run_in_executor(None, client.reconnect)
        except Exception as exc:  # OSError, TLS and address errors alike: retried after the backoff
            self._answer = answer_to_error(exc)
            tls = is_tls_failure(exc)
            self._attempt_failed("TLS handshake failed" if tls else "connect failed", exc)
            return False
        finally:
            self._connecting = False
        sock = client.socket()
        if self._client is not client or sock is None:  # stopped meanwhile, or paho gave the socket up
            self._close_socket(client)
            return False
        self._previous_unsent = False  # CONNECT left: a later failure is not "unsent"
        self._watch(loop, client, sock)
        return True

    def _attempt_failed(self, what: str, cause: BaseException | str, reason: str | None = None) -> None:
        """WARNING when an outage starts or its reason changes, then summarised (edge.publish.broker_trouble)."""
        self._attempt_reported = True
        self.trouble.failed(what, cause, connect_failure.hint(str(cause), self._settings), reason)

    def _watch(self, loop: asyncio.AbstractEventLoop, client: paho.Client, sock: Any) -> None:
        # paho leaves Nagle on: a reply or DATA sent while an earlier packet is unacknowledged would wait
        # for the broker's delayed ACK (~40 ms). Each flush already hands the kernel whole packets.
        with contextlib.suppress(OSError, AttributeError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._watched = sock
        self._writer_added = False
        client.on_socket_register_write = self._paho_want_write
        client.on_socket_unregister_write = self._paho_written
        loop.add_reader(sock, self._readable, client)
        if client.want_write():
            self._schedule_flush(client)
        self._misc_handle = loop.call_later(MISC_INTERVAL_S, self._misc, client)

    def _unwatch(self) -> None:
        """Stop watching the current socket (before paho closes it, so a reused fd number is never ours)."""
        sock, self._watched = self._watched, None
        self._batch.clear()  # never sent on another connection: its seq numbers belong to this one
        self._batch_bytes = 0
        self._wake_room_waiters()
        if self._misc_handle is not None:
            self._misc_handle.cancel()
            self._misc_handle = None
        if sock is None or self._loop is None:
            return
        self._loop.remove_reader(sock)
        if self._writer_added:
            self._loop.remove_writer(sock)
            self._writer_added = False
        if self._session_over is not None:
            self._session_over.set()

    def _close_socket(self, client: paho.Client) -> None:
        self._unwatch()
        sock = client.socket()
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def _readable(self, client: paho.Client) -> None:
        rc = client.loop_read()
        # TLS may hold decrypted bytes the kernel no longer reports: read them now.
        while rc == MQTTErrorCode.MQTT_ERR_SUCCESS and _tls_pending(client.socket()):
            rc = client.loop_read()
        if self._room_waiters:  # PUBACKs free QoS 1 messages
            self._wake_room_waiters()

    def _flush(self, client: paho.Client) -> None:
        """Write what paho queued (all messages published since the last flush); if the kernel buffer
        fills, the rest waits for the socket to become writable."""
        sock = self._watched
        if sock is None or client.socket() is not sock:
            self._flush_scheduled = False
            self._batch.clear()
            self._batch_bytes = 0
            return
        self._queue_batch(client)  # still marked scheduled: paho's write request adds no second flush
        self._flush_scheduled = False
        client.loop_write()
        if client.want_write() and self._watched is sock and not self._writer_added and self._loop is not None:
            self._loop.add_writer(sock, self._flush, client)
            self._writer_added = True
        if self._room_waiters:
            self._wake_room_waiters()

    def _schedule_flush(self, client: paho.Client) -> None:
        if not self._flush_scheduled and self._loop is not None:
            self._flush_scheduled = True
            self._loop.call_soon(self._flush, client)

    def _misc(self, client: paho.Client) -> None:
        self._misc_handle = None
        if client.socket() is None or self._watched is None or self._loop is None:
            return
        client.loop_misc()
        if self._watched is not None:
            self._misc_handle = self._loop.call_later(MISC_INTERVAL_S, self._misc, client)

    # -- operations (event loop) ---------------------------------------------------------------------

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False,
                properties: Properties | None = None) -> bool:
        """Queue a message; False if it cannot be sent now (not connected). Never blocks."""
        client = self._client
        if client is None or not self.connected:
            return False
        if qos == 0 and properties is None and type(payload) is bytes and self._watched is not None:
            prefix = self._topics.prefix(topic, retain)
            if prefix is not None:
                packet = mqtt_wire.publish_packet(prefix, payload)
                self._batch.append(packet)
                self._batch_bytes += len(packet)
                self._schedule_flush(client)
                return True
        self._queue_batch(client)
        info = client.publish(topic, payload, qos=qos, retain=retain, properties=properties)
        return info.rc == MQTTErrorCode.MQTT_ERR_SUCCESS

    def _queue_batch(self, client: paho.Client) -> None:
        """Hand this turn's QoS 0 packets to paho, ahead of anything paho queues next, in writes of about
        RAW_WRITE_BYTES (one write when the turn's packets are fewer)."""
        batch = self._batch
        if not batch:
            return
        if self._batch_bytes <= RAW_WRITE_BYTES:
            mqtt_wire.queue_raw(client, b"".join(batch) if len(batch) > 1 else batch[0])
        else:
            start, size = 0, 0
            for end, packet in enumerate(batch, 1):
                size += len(packet)
                if size >= RAW_WRITE_BYTES:
                    mqtt_wire.queue_raw(client, b"".join(batch[start:end]))
                    start, size = end, 0
            if start < len(batch):
                mqtt_wire.queue_raw(client, b"".join(batch[start:]))
        batch.clear()
        self._batch_bytes = 0

    @property
    def held(self) -> int:
        """Bytes this connection holds for the broker: this turn's packets, what the kernel has not taken,
        QoS 1 messages not yet acknowledged."""
        client = self._client
        return self._batch_bytes + (mqtt_wire.held_bytes(client) if client is not None else 0)

    async def wait_for_room(self, limit: int) -> None:
        """Return once at most `limit` bytes are held (`held`), or the socket is gone (the caller checks
        the connection): a bulk sender (the replay) goes at the pace the broker takes its messages, instead
        of queueing them in memory."""
        loop = asyncio.get_running_loop()
        while self._watched is not None and self.held > limit:
            waiter: asyncio.Future[None] = loop.create_future()
            self._room_waiters.append(waiter)
            await waiter

    def _wake_room_waiters(self) -> None:
        waiters, self._room_waiters = self._room_waiters, []
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(None)

    async def publish_confirmed(self, topic: str, payload: bytes, *, qos: int = 1, retain: bool = False,
                                timeout: float = 5.0) -> None:
        """Publish at QoS 1 and wait for the PUBACK (messages that must land before a DISCONNECT)."""
        client = self._client
        if client is None or not self.connected:
            raise MqttUnavailable(f"cannot publish {topic}: not connected")
        client.on_publish = self._paho_publish  # before the publish: the PUBACK may come in the same turn
        self._queue_batch(client)
        info = client.publish(topic, payload, qos=qos, retain=retain)
        if info.rc != MQTTErrorCode.MQTT_ERR_SUCCESS:
            self._publish_notices_if_needed(client)
            raise MqttUnavailable(f"cannot publish {topic}: {paho.error_string(info.rc)}")
        if qos == 0:
            self._publish_notices_if_needed(client)
            return
        await self._wait(info.mid, timeout, f"PUBACK for {topic}")

    async def subscribe(self, topics: Sequence[tuple[str, int]], timeout: float = 10.0) -> None:
        """Subscribe and wait for the SUBACK; raises MqttUnavailable if refused or not acknowledged."""
        client = self._client
        if client is None or not self.connected:
            raise MqttUnavailable("cannot subscribe: not connected")
        self._queue_batch(client)
        rc, mid = client.subscribe(list(topics))
        if rc != MQTTErrorCode.MQTT_ERR_SUCCESS or mid is None:
            raise MqttUnavailable(f"subscribe {topics}: {paho.error_string(rc)}")
        codes = await self._wait(mid, timeout, f"SUBACK for {[t for t, _ in topics]}")
        refused = [t for (t, _), c in zip(topics, codes, strict=False) if c.is_failure]
        if refused:
            raise MqttUnavailable(f"broker refused subscriptions {refused}")

    async def _wait(self, mid: int, timeout: float, what: str) -> Any:
        fut = asyncio.get_running_loop().create_future()
        self._pending[mid] = fut
        try:
            async with asyncio.timeout(timeout):  # not wait_for: see edge.focas.session._guarded
                return await fut
        except TimeoutError:
            raise MqttUnavailable(f"no {what} within {timeout}s from {self._settings.host}:"
                                  f"{self._settings.port}") from None
        finally:
            self._pending.pop(mid, None)
            client = self._client
            if client is not None:
                self._publish_notices_if_needed(client)

    def _publish_notices_if_needed(self, client: paho.Client) -> None:
        """Report publishes (PUBACKs) only while someone waits for one."""
        if not self._pending:
            client.on_publish = None

    # -- paho callbacks (all on the event loop, but for on_pre_connect: in the connect worker) ----------

    def _delay(self) -> float:
        return retry_delay(self._attempt, self._settings, self._answer)

    def _paho_pre_connect(self, client: paho.Client, userdata: object) -> None:
        will = self._before_connect(self._previous_unsent)
        self._previous_unsent = True  # until the socket is up and CONNECT left
        self._will_tag = None
        if will is None:
            client.will_clear()
            return
        client.will_set(will.topic, will.payload, qos=will.qos, retain=will.retain)
        self._will_tag = will.tag

    def _paho_want_write(self, client: paho.Client, userdata: object, sock: Any) -> None:
        self._schedule_flush(client)

    def _paho_written(self, client: paho.Client, userdata: object, sock: Any) -> None:
        if self._writer_added and self._loop is not None and sock is self._watched:
            self._loop.remove_writer(sock)
            self._writer_added = False

    def _paho_socket_close(self, client: paho.Client, userdata: object, sock: Any) -> None:
        if threading.get_ident() == self._loop_thread and sock is self._watched:
            self._unwatch()

    def _paho_connect(self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode,
                      properties: Properties | None) -> None:
        if reason.is_failure:
            self._answer = answer_to_connack(reason.value)
            self._attempt_failed("connection refused", str(reason),
                                 NOT_AUTHORISED if reason.value in (0x04, 0x05, 0x86, 0x87, 0x8C) else None)
            return  # paho closes the socket; the supervisor retries after the backoff delay
        client.on_log = None  # formatting every paho log line costs on the publish path
        self._back_at_once = self._attempt == 1
        self._attempt = 0
        # QoS 1 messages of the previous connection would be re-sent by paho now, before our births and
        # with a stale Sparkplug seq; the publisher's spool re-sends their samples instead.
        stale = client.drop_out_messages()
        if stale:
            log.info("dropped %d unacknowledged message(s) of the previous connection client_id=%s",
                     len(stale), self._client_id)
        self._defer(self._loop_connected, self._will_tag)

    def _paho_log(self, client: paho.Client, userdata: object, level: int, buf: str) -> None:
        if level == paho.MQTT_LOG_ERR and self._attempt_error is None:
            self._attempt_error = buf

    def _paho_disconnect(self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode,
                         properties: Properties | None) -> None:
        if not self.connected and not self._attempt_reported:
            # Closed before CONNACK: say what the attempt met now, before the supervisor (woken by the
            # socket's close) draws the next delay; the line is logged on the loop (_loop_disconnected).
            self._answer = answer_to_close(self._attempt_error or str(reason), self._settings.tls)
        self._defer(self._loop_disconnected, str(reason))

    def _paho_message(self, client: paho.Client, userdata: object, message: paho.MQTTMessage) -> None:
        response_topic = correlation = None
        props = message.properties
        if props is not None:
            response_topic = getattr(props, "ResponseTopic", None)
            correlation = getattr(props, "CorrelationData", None)
        msg = InboundMessage(message.topic, bytes(message.payload), bool(message.retain),
                             response_topic, correlation)
        self._defer(self._on_message, msg)

    def _paho_subscribe(self, client: paho.Client, userdata: object, mid: int,
                        reason_codes: list[ReasonCode], properties: Properties | None) -> None:
        self._resolve(mid, list(reason_codes))

    def _paho_publish(self, client: paho.Client, userdata: object, mid: int, reason: ReasonCode,
                      properties: Properties | None) -> None:
        self._resolve(mid, reason)

    # -- event loop side -------------------------------------------------------------------------------

    def _defer(self, func: Callable[..., None], *args: object) -> None:
        """Run `func` in the next loop turn, outside paho's own call stack (it holds its callback lock)."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon(func, *args)

    def _resolve(self, mid: int, result: object) -> None:
        fut = self._pending.get(mid)
        if fut is not None and not fut.done():
            fut.set_result(result)

    def _loop_connected(self, tag: object) -> None:
        if self._client is None:
            return
        self.connected = True
        self.connects += 1
        self._dropping = False
        if self._loop is not None:
            self._connected_at = self._loop.time()
        lost, self._lost = self._lost, None
        if lost is not None and self._back_at_once and self._on_lost is not None:
            self._on_lost(*lost)
        log.info("MQTT connected host=%s port=%s client_id=%s protocol=%s", self._settings.host,
                 self._settings.port, self._client_id, self._settings.protocol)
        recovered = self.trouble.up()
        if recovered:
            log.info("%s", recovered)
        self._on_connected(tag)

    def _loop_disconnected(self, reason: str) -> None:
        if not self.connected and not self._attempt_reported and self._client is not None:
            # Closed between CONNECT and CONNACK (a broker refusing our certificate): said as a bad password is.
            cause = self._attempt_error or reason
            self._attempt_failed(*connect_failure.closed_before_connack(cause, self._settings.tls))
        if self.connected:
            stopping = self._client is None  # stop() clears it first: a disconnect we asked for
            if not stopping:
                self.trouble.lost(reason)
            log.log(logging.INFO if stopping else logging.WARNING,
                    "MQTT %s host=%s port=%s client_id=%s reason=%s", "disconnected" if stopping else "connection lost",
                    self._settings.host, self._settings.port, self._client_id, reason)
            if not stopping and not self._dropping and self._loop is not None:
                self._lost = (self._loop.time() - self._connected_at, reason)
        self._set_disconnected()

    def _set_disconnected(self) -> None:
        was = self.connected
        self.connected = False
        self.trouble.down()
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(MqttUnavailable("connection lost"))
        if was:
            self._on_disconnected()


def _tls_pending(sock: Any) -> int:
    """Bytes a TLS socket has decrypted but not handed out (0 for plain sockets and no socket)."""
    pending = getattr(sock, "pending", None)
    return int(pending()) if pending is not None else 0


def response_properties(correlation_data: bytes | None) -> Properties:
    """PUBLISH properties for an MQTT 5 reply: the request's correlation data, if any."""
    props = Properties(PacketTypes.PUBLISH)
    if correlation_data is not None:
        props.CorrelationData = correlation_data
    return props
