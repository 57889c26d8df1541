"""The reconnect delay: a prompt probe while nobody listens, a short capped retry while the broker's address
accepts and does not serve, the growing backoff while the broker rejects the attempt on its merits."""

from __future__ import annotations

import errno
import random
import socket
import ssl

from edge.publish.broker_trouble import Answer, answer_to_close, answer_to_connack, answer_to_error, nobody_answered
from edge.publish.mqtt import retry_delay
from edge.publish.settings import PublishSettings


def test_an_attempt_nobody_answered_is_retried_within_the_probe_delay_however_many_failed() -> None:
    settings = PublishSettings(reconnect_min_s=0.5, reconnect_max_s=30.0, reconnect_probe_s=1.0)
    rng = random.Random(3)
    for attempt in range(40):
        delays = [retry_delay(attempt, settings, Answer.NOBODY, rng) for _ in range(50)]
        assert all(d <= 1.0 for d in delays)
        if attempt >= 2:  # past the backoff's own short delays: drawn in [probe / 2, probe], not in lock-step
            assert all(d >= 0.5 for d in delays) and len(set(delays)) > 1


def test_a_broker_that_rejects_the_attempt_keeps_the_growing_backoff() -> None:
    settings = PublishSettings(reconnect_min_s=0.5, reconnect_max_s=30.0, reconnect_probe_s=1.0)
    rng = random.Random(5)
    assert all(15.0 <= retry_delay(10, settings, Answer.REJECTED, rng) <= 30.0 for _ in range(50))


def test_a_broker_not_serving_is_retried_within_its_cap_and_never_sooner_than_half_of_it() -> None:
    settings = PublishSettings(reconnect_min_s=0.5, reconnect_max_s=30.0, reconnect_not_serving_s=2.0)
    rng = random.Random(7)
    for attempt in range(40):
        delays = [retry_delay(attempt, settings, Answer.NOT_SERVING, rng) for _ in range(50)]
        assert all(1.0 <= d <= 2.0 for d in delays), attempt  # the floor from the first retry on
        if attempt >= 3:  # past the backoff's own short delays: jittered, not in lock-step
            assert len(set(delays)) > 1


def test_the_capped_delays_never_exceed_the_backoff_cap() -> None:
    settings = PublishSettings(reconnect_min_s=0.05, reconnect_max_s=0.2, reconnect_probe_s=1.0)
    assert all(retry_delay(20, settings, Answer.NOBODY) <= 0.2 for _ in range(50))
    assert all(0.1 <= retry_delay(20, settings, Answer.NOT_SERVING) <= 0.2 for _ in range(50))


def test_which_failures_reached_no_broker() -> None:
    assert nobody_answered(ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused"))
    assert nobody_answered(TimeoutError("timed out"))
    assert nobody_answered(OSError(errno.EHOSTUNREACH, "No route to host"))
    assert nobody_answered(OSError(errno.ENETUNREACH, "Network is unreachable"))
    # Answers: a name server that knows no such name, a TLS peer, a reset by a peer that accepted.
    assert not nobody_answered(socket.gaierror(socket.EAI_NONAME, "Name or service not known"))
    assert not nobody_answered(ssl.SSLError(1, "certificate verify failed"))
    assert not nobody_answered(ConnectionResetError(errno.ECONNRESET, "reset"))
    assert not nobody_answered(ValueError("bad address"))


def test_what_a_failed_attempt_met() -> None:
    assert answer_to_error(ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused")) is Answer.NOBODY
    assert answer_to_error(ConnectionResetError(errno.ECONNRESET, "reset")) is Answer.NOT_SERVING
    assert answer_to_error(BrokenPipeError(errno.EPIPE, "broken pipe")) is Answer.NOT_SERVING
    assert answer_to_error(ssl.SSLEOFError(8, "EOF occurred in violation of protocol")) is Answer.NOT_SERVING
    assert answer_to_error(ssl.SSLError(1, "certificate verify failed")) is Answer.REJECTED
    assert answer_to_error(socket.gaierror(socket.EAI_NONAME, "Name or service not known")) is Answer.REJECTED
    # Closed before CONNACK: paho's first error of the attempt, or the disconnect's reason.
    assert answer_to_close("Unspecified error") is Answer.NOT_SERVING
    assert answer_to_close("failed to receive on socket: [Errno 104] Connection reset by peer") is Answer.NOT_SERVING
    assert answer_to_close("failed to receive on socket: [SSL: TLSV13_ALERT_CERTIFICATE_REQUIRED] tlsv13 alert "
                           "certificate required") is Answer.REJECTED
    # On a TLS link the broker finished its handshake: an aborted session before CONNACK is the broker refusing
    # this client (TLS 1.3 checks the client certificate after the client's handshake; the alert is mostly
    # lost to the close), not a broker that is restarting; a clean close stays "not serving".
    eof = "failed to receive on socket: EOF occurred in violation of protocol (_ssl.c:2427)"
    reset = "failed to receive on socket: [Errno 104] Connection reset by peer"
    assert answer_to_close(eof, tls=True) is Answer.REJECTED
    assert answer_to_close(reset, tls=True) is Answer.REJECTED
    assert answer_to_close(reset, tls=False) is Answer.NOT_SERVING
    assert answer_to_close("Unspecified error", tls=True) is Answer.NOT_SERVING
    # During the handshake (the connect raised): a TLS proxy in front of a broker that is down, still fast.
    assert answer_to_error(ConnectionResetError(errno.ECONNRESET, "reset")) is Answer.NOT_SERVING
    # CONNACK refusals: server unavailable (3.1.1's 3 as paho reports it) and busy pass; a bad login does not.
    assert answer_to_connack(0x88) is Answer.NOT_SERVING and answer_to_connack(0x89) is Answer.NOT_SERVING
    assert answer_to_connack(0x86) is Answer.REJECTED and answer_to_connack(0x87) is Answer.REJECTED
    assert answer_to_connack(0x9F) is Answer.REJECTED  # connection rate exceeded: back off
