"""One MQTT connection (paho-mqtt 2.x) with its network loop in paho's thread and events on asyncio.

What this adds to paho:
- every callback is handed to the event loop with call_soon_threadsafe, so the rest of the publisher is
  single-threaded;
- a fresh Will before *every* CONNECT, automatic reconnects included (`before_connect`, from paho's
  on_pre_connect), which is how Sparkplug's bdSeq advances;
- clean session (3.1.1) / clean start with session expiry 0 (5) on every attempt: paho's MQTT 5 default,
  clean start on the first connect only, would break Sparkplug on reconnect;
- reconnect delays that grow exponentially to a cap, each drawn with jitter so a fleet does not reconnect in
  lock-step after a broker restart;
- awaitable SUBACK / PUBACK;
- nothing of a previous connection is re-sent after a reconnect (the publisher's spool owns redelivery).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import random
import socket
import ssl
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion, MQTTErrorCode
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from edge.publish.settings import PublishSettings

log = logging.getLogger(__name__)


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


class MqttConnection:
    """A supervised connection; create and use it on the event loop that receives its callbacks."""

    def __init__(self, settings: PublishSettings, client_id: str, *,
                 before_connect: Callable[[bool], Will | None],
                 on_connected: Callable[[object], None],
                 on_disconnected: Callable[[], None],
                 on_message: Callable[[InboundMessage], None]) -> None:
        self._settings = settings
        self._client_id = client_id
        self._before_connect = before_connect
        self._on_connected = on_connected
        self._on_disconnected = on_disconnected
        self._on_message = on_message
        self._v5 = settings.protocol == "5"
        self._loop: asyncio.AbstractEventLoop | None = None
        self._client: paho.Client | None = None
        self._attempt = 0  # failed attempts since the last CONNACK (paho thread only)
        self._previous_unsent = False  # the previous attempt failed before CONNECT left (paho thread only)
        self._will_tag: object = None
        self._pending: dict[int, asyncio.Future[Any]] = {}
        # PUBACKs (and QoS 0 "written" notices) from the paho thread, drained by the loop in batches:
        # one loop wake-up per batch instead of one per message (QoS 0 DATA is ~all the traffic).
        self._acks: collections.deque[tuple[int, object]] = collections.deque()
        self._acks_scheduled = False
        self.connected = False  # as seen on the event loop
        self.connects = 0

    # -- lifecycle -----------------------------------------------------------------------------------

    def start(self) -> None:
        """Begin connecting in the background; on_connected is called (on the loop) once it succeeds."""
        self._loop = asyncio.get_running_loop()
        client = self._make_client()
        self._client = client
        s = self._settings
        kwargs: dict[str, Any] = {}
        if self._v5:
            kwargs["clean_start"] = True  # every attempt; session expiry stays 0 (property absent)
        client.connect_async(s.host, s.port, keepalive=s.keepalive, **kwargs)
        client.loop_start()

    def _make_client(self) -> paho.Client:
        s = self._settings
        protocol = paho.MQTTv5 if self._v5 else paho.MQTTv311
        kwargs: dict[str, Any] = {} if self._v5 else {"clean_session": True}
        client = paho.Client(CallbackAPIVersion.VERSION2, client_id=self._client_id, protocol=protocol,
                             reconnect_on_failure=True, **kwargs)
        if s.username is not None:
            client.username_pw_set(s.username, s.password)
        if s.tls:
            client.tls_set(ca_certs=str(s.tls_ca_file) if s.tls_ca_file else None,
                           certfile=str(s.tls_cert_file) if s.tls_cert_file else None,
                           keyfile=str(s.tls_key_file) if s.tls_key_file else None,
                           cert_reqs=ssl.CERT_REQUIRED)
            if s.tls_insecure:
                client.tls_insecure_set(True)
        _set_retry_delay(client, self._delay(), self._settings.reconnect_max_s)
        client.on_pre_connect = self._paho_pre_connect
        client.on_connect = self._paho_connect
        client.on_connect_fail = self._paho_connect_fail
        client.on_disconnect = self._paho_disconnect
        client.on_message = self._paho_message
        client.on_subscribe = self._paho_subscribe
        client.on_publish = self._paho_publish
        return client

    async def stop(self, *, with_will: bool = False, timeout: float = 5.0) -> None:
        """DISCONNECT and end the network thread.

        MQTT 5 `with_will`: reason 0x04 "disconnect with will message", so the broker sends the Will too.
        """
        client, self._client = self._client, None
        if client is None:
            return
        if self._v5 and with_will:
            client.disconnect(reasoncode=ReasonCode(PacketTypes.DISCONNECT, "Disconnect with will message"))
        else:
            client.disconnect()
        try:
            await asyncio.wait_for(asyncio.to_thread(client.loop_stop), timeout)
        except TimeoutError:
            log.warning("MQTT network thread did not stop within %ss client_id=%s", timeout, self._client_id)
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
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    # -- operations (event loop) ---------------------------------------------------------------------

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False,
                properties: Properties | None = None) -> bool:
        """Queue a message; False if it cannot be sent now (not connected). Never blocks."""
        client = self._client
        if client is None or not self.connected:
            return False
        info = client.publish(topic, payload, qos=qos, retain=retain, properties=properties)
        return info.rc == MQTTErrorCode.MQTT_ERR_SUCCESS

    async def publish_confirmed(self, topic: str, payload: bytes, *, qos: int = 1, retain: bool = False,
                                timeout: float = 5.0) -> None:
        """Publish at QoS 1 and wait for the PUBACK (messages that must land before a DISCONNECT)."""
        client = self._client
        if client is None or not self.connected:
            raise MqttUnavailable(f"cannot publish {topic}: not connected")
        info = client.publish(topic, payload, qos=qos, retain=retain)
        if info.rc != MQTTErrorCode.MQTT_ERR_SUCCESS:
            raise MqttUnavailable(f"cannot publish {topic}: {paho.error_string(info.rc)}")
        if qos == 0:
            return
        await self._wait(info.mid, timeout, f"PUBACK for {topic}")

    async def subscribe(self, topics: Sequence[tuple[str, int]], timeout: float = 10.0) -> None:
        """Subscribe and wait for the SUBACK; raises MqttUnavailable if refused or not acknowledged."""
        client = self._client
        if client is None or not self.connected:
            raise MqttUnavailable("cannot subscribe: not connected")
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

    # -- paho thread -> event loop ---------------------------------------------------------------------

    def _to_loop(self, func: Callable[..., None], *args: object) -> bool:
        """Run `func` on the event loop; False if there is no loop to run it (stopped, closed)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return False
        try:
            loop.call_soon_threadsafe(func, *args)
        except RuntimeError:  # the loop closed between the check and the call
            return False
        return True

    def _delay(self) -> float:
        s = self._settings
        return backoff_delay(self._attempt, s.reconnect_min_s, s.reconnect_max_s)

    def _schedule_retry(self, client: paho.Client) -> None:
        delay = self._delay()
        self._attempt += 1
        _set_retry_delay(client, delay, delay)  # paho waits exactly this long before the next attempt

    def _paho_pre_connect(self, client: paho.Client, userdata: object) -> None:
        will = self._before_connect(self._previous_unsent)
        self._previous_unsent = True  # until the socket is up and CONNECT left
        self._will_tag = None
        if will is None:
            client.will_clear()
            return
        client.will_set(will.topic, will.payload, qos=will.qos, retain=will.retain)
        self._will_tag = will.tag

    def _paho_connect(self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode,
                      properties: Properties | None) -> None:
        self._previous_unsent = False
        if reason.is_failure:
            log.warning("MQTT connection refused host=%s port=%s client_id=%s reason=%s",
                        self._settings.host, self._settings.port, self._client_id, reason)
            self._schedule_retry(client)
            return
        self._attempt = 0
        # QoS 1 messages of the previous connection would be re-sent by paho now, before our births and
        # with a stale Sparkplug seq; the publisher's spool re-sends their samples instead.
        stale = client.drop_out_messages()
        if stale:
            log.info("dropped %d unacknowledged message(s) of the previous connection client_id=%s",
                     len(stale), self._client_id)
        self._to_loop(self._loop_connected, self._will_tag)

    def _paho_connect_fail(self, client: paho.Client, userdata: object) -> None:
        log.info("MQTT connect failed host=%s port=%s client_id=%s attempt=%d",
                 self._settings.host, self._settings.port, self._client_id, self._attempt + 1)
        self._schedule_retry(client)

    def _paho_disconnect(self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode,
                         properties: Properties | None) -> None:
        self._previous_unsent = False
        self._schedule_retry(client)
        self._to_loop(self._loop_disconnected, str(reason))

    def _paho_message(self, client: paho.Client, userdata: object, message: paho.MQTTMessage) -> None:
        response_topic = correlation = None
        props = message.properties
        if props is not None:
            response_topic = getattr(props, "ResponseTopic", None)
            correlation = getattr(props, "CorrelationData", None)
        msg = InboundMessage(message.topic, bytes(message.payload), bool(message.retain),
                             response_topic, correlation)
        self._to_loop(self._on_message, msg)

    def _paho_subscribe(self, client: paho.Client, userdata: object, mid: int,
                        reason_codes: list[ReasonCode], properties: Properties | None) -> None:
        self._to_loop(self._resolve, mid, list(reason_codes))

    def _paho_publish(self, client: paho.Client, userdata: object, mid: int, reason: ReasonCode,
                      properties: Properties | None) -> None:
        # Append first, then schedule a drain only if none is pending: the drain clears the flag before
        # it empties the queue, so an ack appended meanwhile is either drained now or schedules another.
        self._acks.append((mid, reason))
        if not self._acks_scheduled:
            self._acks_scheduled = True
            if not self._to_loop(self._drain_acks):
                self._acks_scheduled = False

    # -- event loop side -------------------------------------------------------------------------------

    def _drain_acks(self) -> None:
        self._acks_scheduled = False
        acks = self._acks
        pending = self._pending
        while acks:
            mid, reason = acks.popleft()
            if mid in pending:
                self._resolve(mid, reason)

    def _resolve(self, mid: int, result: object) -> None:
        fut = self._pending.get(mid)
        if fut is not None and not fut.done():
            fut.set_result(result)

    def _loop_connected(self, tag: object) -> None:
        if self._client is None:
            return
        self.connected = True
        self.connects += 1
        log.info("MQTT connected host=%s port=%s client_id=%s protocol=%s", self._settings.host,
                 self._settings.port, self._client_id, self._settings.protocol)
        self._on_connected(tag)

    def _loop_disconnected(self, reason: str) -> None:
        if self.connected:
            stopping = self._client is None  # stop() clears it first: a disconnect we asked for
            log.log(logging.INFO if stopping else logging.WARNING,
                    "MQTT %s host=%s port=%s client_id=%s reason=%s", "disconnected" if stopping else "connection lost",
                    self._settings.host, self._settings.port, self._client_id, reason)
        self._set_disconnected()

    def _set_disconnected(self) -> None:
        was = self.connected
        self.connected = False
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(MqttUnavailable("connection lost"))
        if was:
            self._on_disconnected()


def _set_retry_delay(client: paho.Client, first: float, cap: float) -> None:
    # paho annotates int seconds but computes with floats; sub-second delays keep tests and LANs snappy
    client.reconnect_delay_set(first, cap)  # type: ignore[arg-type]


def response_properties(correlation_data: bytes | None) -> Properties:
    """PUBLISH properties for an MQTT 5 reply: the request's correlation data, if any."""
    props = Properties(PacketTypes.PUBLISH)
    if correlation_data is not None:
        props.CorrelationData = correlation_data
    return props
