"""The reconnect delay: the growing backoff while the broker answers, a prompt probe while nobody listens."""

from __future__ import annotations

import errno
import random
import socket
import ssl

from edge.publish.broker_trouble import nobody_answered
from edge.publish.mqtt import retry_delay
from edge.publish.settings import PublishSettings


def test_an_attempt_nobody_answered_is_retried_within_the_probe_delay_however_many_failed() -> None:
    settings = PublishSettings(reconnect_min_s=0.5, reconnect_max_s=30.0, reconnect_probe_s=1.0)
    rng = random.Random(3)
    for attempt in range(40):
        delays = [retry_delay(attempt, settings, True, rng) for _ in range(50)]
        assert all(d <= 1.0 for d in delays)
        if attempt >= 2:  # past the backoff's own short delays: drawn in [probe / 2, probe], not in lock-step
            assert all(d >= 0.5 for d in delays) and len(set(delays)) > 1


def test_a_broker_that_answers_keeps_the_growing_backoff() -> None:
    settings = PublishSettings(reconnect_min_s=0.5, reconnect_max_s=30.0, reconnect_probe_s=1.0)
    rng = random.Random(5)
    assert all(15.0 <= retry_delay(10, settings, False, rng) <= 30.0 for _ in range(50))


def test_the_probe_delay_never_exceeds_the_backoff_cap() -> None:
    settings = PublishSettings(reconnect_min_s=0.05, reconnect_max_s=0.2, reconnect_probe_s=1.0)
    assert all(retry_delay(20, settings, True) <= 0.2 for _ in range(50))


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
