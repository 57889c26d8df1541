"""Broker trouble in the log: one WARNING naming host:port and the reason, one a minute while it lasts, one
line when it recovers; and the state the status page shows."""

from __future__ import annotations

import logging
import socket
import ssl

import pytest

from edge.publish.broker_trouble import (
    NOT_AUTHORISED,
    REFUSED,
    TLS,
    UNRESOLVABLE,
    BrokerTrouble,
    classify,
    duration_text,
    is_tls_failure,
)

LOGGER = logging.getLogger("test.broker_trouble")


class Clocks:
    def __init__(self) -> None:
        self.mono = 100.0
        self.wall = 1_800_000_000.0

    def advance(self, seconds: float) -> None:
        self.mono += seconds
        self.wall += seconds


def tracker(clocks: Clocks) -> BrokerTrouble:
    return BrokerTrouble("broker.plant", 1883, "gw", LOGGER, clock=lambda: clocks.mono, wall=lambda: clocks.wall)


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOGGER.name and r.levelno >= logging.WARNING]


@pytest.mark.parametrize(("error", "reason"), [
    (ConnectionRefusedError(111, "Connection refused"), REFUSED),
    (socket.gaierror(-2, "Name or service not known"), UNRESOLVABLE),
    (ssl.SSLCertVerificationError("certificate verify failed"), TLS),
    ("Not authorized", NOT_AUTHORISED),
    ("Bad user name or password", NOT_AUTHORISED),
    ("[Errno 111] Connection refused", REFUSED),
])
def test_the_reason_is_named(error: BaseException | str, reason: str) -> None:
    assert classify(error) == reason


def test_an_outage_is_one_warning_then_one_a_minute_with_a_count_then_one_line_at_recovery(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger=LOGGER.name)
    clocks = Clocks()
    trouble = tracker(clocks)
    refused = ConnectionRefusedError(111, "Connection refused")
    for _ in range(12):  # every 5 s for a minute less a little
        trouble.failed("connect failed", refused)
        clocks.advance(5)
    lines = warnings(caplog)
    assert len(lines) == 1, lines
    assert "broker=broker.plant:1883" in lines[0] and "reason=refused" in lines[0]
    trouble.failed("connect failed", refused)  # 60 s after the first line
    lines = warnings(caplog)
    assert len(lines) == 2 and "still unavailable" in lines[1] and "failed_attempts=13" in lines[1], lines
    assert "(12 since the last line)" in lines[1] and "down_for=1m00s" in lines[1]
    state = trouble.state()
    assert (state.connected, state.failed_attempts, state.reason) == (False, 13, REFUSED)
    assert "Connection refused" in state.last_error
    clocks.advance(10)
    recovered = trouble.up()
    assert "available again" in recovered and "down_for=1m10s" in recovered and "failed_attempts=13" in recovered
    assert trouble.state().connected and trouble.state().since == clocks.wall


def test_a_new_reason_is_said_at_once(caplog: pytest.LogCaptureFixture) -> None:
    clocks = Clocks()
    trouble = tracker(clocks)
    trouble.failed("connect failed", ConnectionRefusedError(111, "Connection refused"))
    clocks.advance(5)
    trouble.failed("connection refused", "Not authorized")
    lines = warnings(caplog)
    assert len(lines) == 2 and "reason=not authorised" in lines[1], lines
    for _ in range(5):  # a cause that flaps between two reasons says each once, not every attempt
        clocks.advance(5)
        trouble.failed("connect failed", ConnectionRefusedError(111, "Connection refused"))
        clocks.advance(5)
        trouble.failed("connection refused", "Not authorized")
    assert len(warnings(caplog)) == 2


def test_a_lost_session_starts_an_outage_measured_from_the_loss(caplog: pytest.LogCaptureFixture) -> None:
    clocks = Clocks()
    trouble = tracker(clocks)
    assert trouble.up() == ""  # the first connect is no recovery
    clocks.advance(30)
    trouble.lost("keepalive timeout")
    lost_at = clocks.wall
    assert not trouble.state().connected and trouble.state().since == lost_at
    clocks.advance(2)
    trouble.failed("connect failed", ConnectionRefusedError(111, "Connection refused"))
    clocks.advance(2)
    trouble.failed("connect failed", ConnectionRefusedError(111, "Connection refused"))
    assert len(warnings(caplog)) == 1  # the reconnect's reason, once (the caller logs the loss itself)
    assert "down_for=4s" in trouble.up()


def test_durations_read_as_people_say_them() -> None:
    assert [duration_text(s) for s in (4.4, 64, 7500)] == ["4s", "1m04s", "2h05m"]


@pytest.mark.parametrize(("error", "tls"), [
    (ssl.SSLCertVerificationError("certificate verify failed"), True),
    (ssl.SSLError("tlsv13 alert certificate required"), True),
    (ConnectionRefusedError(111, "Connection refused"), False),
    (OSError("ssl library said no"), False),  # only the error's type decides the "TLS handshake failed" line
])
def test_one_classifier_says_tls_for_the_attempt_line_and_the_reason_alike(error: BaseException, tls: bool) -> None:
    assert is_tls_failure(error) is tls
    if tls:
        assert classify(error) == TLS
