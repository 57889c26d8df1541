"""Broker trouble said once, then summarised: what an MQTT connection's outage looks like in the log.

A broker that is down, refuses, cannot be resolved or rejects the credentials makes the connection retry
every few seconds; one line per attempt buries everything else (and at INFO it hid the outage). So the
first failure of an outage is one WARNING naming host:port and the reason; while it lasts, one WARNING a
minute with the count of failed attempts; when the connection is up again, one line saying how long it
was down. A new reason (refused -> not authorised) is worth a line of its own, once per outage.

The tracker also keeps what the status page, status.json and systemd's STATUS= show: connected since or
down since, and the last error.
"""

from __future__ import annotations

import errno
import logging
import socket
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

SUMMARY_EVERY_S = 60.0

REFUSED = "refused"
UNRESOLVABLE = "unresolvable"
NOT_AUTHORISED = "not authorised"
TLS = "TLS"
TIMED_OUT = "timed out"
UNREACHABLE = "unreachable"
LOST = "connection lost"
CLOSED = "closed before CONNACK"


def is_tls_failure(error: BaseException | str) -> bool:
    """A TLS handshake or certificate verification error (not a refused or unreachable TCP connect)."""
    return isinstance(error, ssl.SSLError | ssl.CertificateError)


# A TCP connect that met these found nobody at the broker's port: the broker never saw the attempt.
_NOBODY_THERE = frozenset({errno.ECONNREFUSED, errno.EHOSTUNREACH, errno.ENETUNREACH, errno.EHOSTDOWN,
                           errno.ETIMEDOUT})


class Answer(Enum):
    """What a failed connect attempt met; it sets how soon the next one goes (edge.publish.mqtt.retry_delay)."""

    NOBODY = "nobody"  # nothing listened at the broker's port: the attempt cost no broker anything
    NOT_SERVING = "not serving"  # accepted, then closed before CONNACK, or CONNACK "server unavailable/busy"
    REJECTED = "rejected"  # turned down on its merits (credentials, TLS, a name): a retry alone does not fix it


# CONNACK reason codes (MQTT 5 numbering; paho maps 3.1.1's "server unavailable" to 0x88) of a broker that
# would take the client but cannot now.
_BUSY_CONNACK = frozenset({0x88, 0x89})


def nobody_answered(error: BaseException) -> bool:
    """The attempt ended before any broker process saw it: the port refused, the host or network was
    unreachable, or the TCP connect timed out. Such an attempt costs the broker nothing, so it may be repeated
    often (edge.publish.mqtt probes at ~0.5 s)."""
    if isinstance(error, socket.gaierror) or is_tls_failure(error):
        return False
    if isinstance(error, TimeoutError | ConnectionRefusedError):
        return True
    return isinstance(error, OSError) and error.errno in _NOBODY_THERE


def answer_to_error(error: BaseException) -> Answer:
    """A connect attempt that raised: nobody there, a peer that accepted and then reset or closed the
    connection (during the TLS handshake too: a proxy in front of a broker that is down; a broker refusing
    the client certificate sends an alert here, or ends the session after the handshake: tls_refused), or a
    rejection (a name that does not resolve, a TLS failure, anything else)."""
    if nobody_answered(error):
        return Answer.NOBODY
    if isinstance(error, ConnectionResetError | ConnectionAbortedError | BrokenPipeError | ssl.SSLEOFError
                  | ssl.SSLZeroReturnError):
        return Answer.NOT_SERVING
    return Answer.REJECTED


# How a peer's abortive close reads in paho's error: an SSL EOF (no close_notify), a reset, a broken pipe.
_ABORTED = ("eof occurred in violation of protocol", "unexpected eof", "connection reset", "broken pipe")


def tls_refused(cause: str, tls: bool) -> bool:
    """On a TLS link, a session closed before its CONNACK by a TLS alert, or aborted (an EOF without
    close_notify, a reset). The broker's TLS stack had finished its side of the handshake, so a broker is
    there and serving TLS: what it turned down is this client. With TLS 1.3 a broker that requires a client
    certificate checks it only after the client has finished its handshake and sent CONNECT, and its alert
    is mostly lost to the close: the client reads an EOF (or a reset), rarely the alert. A broker that is
    down or restarting refuses the TCP connect, or closes during the handshake (edge.publish.mqtt raises
    that in the connect itself: answer_to_error)."""
    text = cause.lower()
    return tls and ("alert" in text or any(words in text for words in _ABORTED))


def answer_to_close(cause: str, tls: bool = False) -> Answer:
    """A connection closed before its CONNACK (`cause`: paho's first error, or the disconnect reason): a
    broker, or a proxy in front of one, that is not serving; unless the cause is a TLS alert, a TLS session
    the broker aborted (`tls`: the link is TLS; tls_refused) or a refused login, which a retry does not fix."""
    text = cause.lower()
    if classify(cause) == NOT_AUTHORISED or "alert" in text or "certificate" in text or tls_refused(cause, tls):
        return Answer.REJECTED
    return Answer.NOT_SERVING


def answer_to_connack(reason_code: int) -> Answer:
    """A CONNACK refusal: "server unavailable" or "server busy" will pass; the rest (credentials, a client id
    or protocol refused, a connect rate exceeded) need a change or a longer wait."""
    return Answer.NOT_SERVING if reason_code in _BUSY_CONNACK else Answer.REJECTED


def classify(error: BaseException | str) -> str:
    """The reason in one word a person acts on: refused, unresolvable, not authorised, TLS, ..."""
    if is_tls_failure(error):
        return TLS
    if isinstance(error, socket.gaierror):
        return UNRESOLVABLE
    if isinstance(error, ConnectionRefusedError):
        return REFUSED
    if isinstance(error, TimeoutError | socket.timeout):
        return TIMED_OUT
    text = str(error).lower()
    for words, reason in ((("not authori", "bad user name", "password", "banned"), NOT_AUTHORISED),
                          (("name or service not known", "nodename nor servname", "temporary failure in name",
                            "no address associated"), UNRESOLVABLE),
                          (("connection refused",), REFUSED),
                          (("certificate", "ssl", "tls"), TLS),
                          (("timed out",), TIMED_OUT),
                          (("no route to host", "network is unreachable", "host is unreachable"), UNREACHABLE)):
        if any(w in text for w in words):
            return reason
    return UNREACHABLE if isinstance(error, OSError) else "error"


def duration_text(seconds: float) -> str:
    """12s, 3m04s, 2h05m: how long an outage lasted, for people."""
    s = round(seconds)
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


@dataclass(frozen=True, slots=True)
class BrokerState:
    """One connection's broker session as the status readers show it (wall times, epoch seconds)."""

    address: str  # host:port
    client_id: str
    connected: bool
    since: float  # connected since, or down since
    last_error: str  # "" until the first failure
    reason: str  # the class of the last error (refused, unresolvable, ...); "" when none
    failed_attempts: int  # in the current outage


class BrokerTrouble:
    """Follows one connection's attempts; logs an outage at its start, once a minute, and at its end."""

    def __init__(self, host: str, port: int, client_id: str, logger: logging.Logger, *,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time,
                 summary_every_s: float = SUMMARY_EVERY_S) -> None:
        self.address = f"{host}:{port}"
        self.client_id = client_id
        self._log = logger
        self._clock = clock
        self._wall = wall
        self._summary_every_s = summary_every_s
        self.connected = False
        self.since = wall()  # down since the start: nothing connected yet
        self._down_at = clock()  # monotonic twin of `since` while down
        self.last_error = ""
        self.reason = ""
        self.failed_attempts = 0  # in this outage
        self._reported: set[str] = set()  # the reasons this outage has said (a flapping cause says each once)
        self._last_line_at = -float("inf")
        self._since_line = 0  # failed attempts since the last line

    def state(self) -> BrokerState:
        return BrokerState(self.address, self.client_id, self.connected, self.since, self.last_error, self.reason,
                           self.failed_attempts)

    def failed(self, what: str, error: BaseException | str, extra: str = "", reason: str | None = None) -> None:
        """A connect attempt failed (`what`: "connect failed", "TLS handshake failed", ...)."""
        reason = reason or classify(error)
        self.failed_attempts += 1
        self._since_line += 1
        self.last_error = f"{what}: {error}" if str(error) else what
        self.reason = reason
        now = self._clock()
        if reason not in self._reported:
            self._reported.add(reason)
            self._line(now, "MQTT %s host=%s port=%s broker=%s client_id=%s reason=%s error=%s%s; retrying, "
                       "summarised once a minute while it lasts", what, *self._host_port(), self.address,
                       self.client_id, reason, error, f" hint={extra}" if extra else "")
        elif now - self._last_line_at >= self._summary_every_s:
            self._line(now, "MQTT broker still unavailable broker=%s client_id=%s down_for=%s reason=%s "
                       "failed_attempts=%d (%d since the last line) last_error=%s", self.address, self.client_id,
                       duration_text(now - self._down_at), reason, self.failed_attempts, self._since_line, error)
        else:
            self._log.debug("MQTT %s broker=%s client_id=%s attempt=%d error=%s", what, self.address,
                            self.client_id, self.failed_attempts, error)

    def up(self) -> str:
        """The session is up (CONNACK accepted); returns the line to log ("" when there was no outage)."""
        was_down = self.failed_attempts > 0 or bool(self._reported)
        line = ""
        if was_down:
            line = (f"MQTT broker available again broker={self.address} client_id={self.client_id} down_for="
                    f"{duration_text(self._clock() - self._down_at)} failed_attempts={self.failed_attempts}")
        self.connected = True
        self.since = self._wall()
        self.failed_attempts = 0
        self._since_line = 0
        self._reported.clear()
        self._last_line_at = -float("inf")
        return line

    def lost(self, reason: str) -> None:
        """An established session ended without our asking: an outage starts (the caller logs the line)."""
        self.down(reason)
        self.reason = LOST
        self._reported = {LOST}
        self._last_line_at = self._clock()

    def down(self, reason: str = "") -> None:
        """The session ended (lost, or stopped by us)."""
        if self.connected:
            self.connected = False
            self.since = self._wall()
            self._down_at = self._clock()
        if reason:
            self.last_error = f"connection lost: {reason}"

    def _host_port(self) -> tuple[str, str]:
        host, _, port = self.address.rpartition(":")
        return host, port

    def _line(self, now: float, message: str, *args: object) -> None:
        self._last_line_at = now
        self._since_line = 0
        self._log.warning(message, *args)
