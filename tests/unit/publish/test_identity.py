"""IdentityGuard: which evidence is a conflict, one ERROR per conflict, the backoff while it lasts, its end."""

from __future__ import annotations

import logging

import pytest

from edge.publish import payload as pl
from edge.publish.identity import IdentityGuard, bdseq_of


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def guard(clock: Clock) -> IdentityGuard:
    return IdentityGuard("Sparkplug id plant/gw", clock=clock, wall=lambda: 1.7e9)


def errors(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]


def test_our_own_nbirth_echo_and_our_own_ndeaths_are_not_a_conflict(guard: IdentityGuard) -> None:
    birth = b"our NBIRTH bytes"
    guard.sent_birth(birth)
    guard.used_bdseq(4)
    guard.nbirth_seen(birth, 4, 4)
    guard.ndeath_seen(4, 5)  # the Will of our previous session
    assert not guard.active and guard.count == 0 and guard.conflict is None
    assert guard.reconnect_floor_s() == 0.0 and guard.rebirth_interval_s(1.0) == 1.0


def test_a_clones_byte_equal_nbirth_is_a_conflict_though_it_matches_ours(
        guard: IdentityGuard, caplog: pytest.LogCaptureFixture) -> None:
    """Two clones with new state_dirs born in the same millisecond send the same bytes: the second copy tells."""
    birth = b"NBIRTH bdSeq 0 at ms 1700000000000"
    guard.sent_birth(birth)
    guard.nbirth_seen(birth, 0, 0)  # our echo
    assert not guard.active
    guard.nbirth_seen(birth, 0, 0)  # the clone's, byte for byte
    (line,) = errors(caplog)
    assert "an NBIRTH for this id from another session" in line and guard.count == 1


def test_each_of_our_births_echoes_once_even_when_two_are_equal(guard: IdentityGuard) -> None:
    """A rebirth within the same millisecond repeats the bytes: two sent, two echoes, no conflict."""
    guard.sent_birth(b"same")
    guard.sent_birth(b"same")
    guard.nbirth_seen(b"same", 0, 0)
    guard.nbirth_seen(b"same", 0, 0)
    assert not guard.active and guard.count == 0


def test_another_sessions_nbirth_is_one_error_then_backoff_until_it_stops(
        guard: IdentityGuard, clock: Clock, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    guard.sent_birth(b"ours")
    guard.nbirth_seen(b"theirs", 0, 0)  # same bdSeq (both state_dirs new): the bytes tell
    guard.nbirth_seen(b"theirs again", 0, 0)
    (line,) = errors(caplog)
    assert "Sparkplug id plant/gw" in line and "an NBIRTH for this id from another session" in line
    assert guard.count == 2 and guard.active
    assert guard.reconnect_floor_s() == 60.0 and guard.rebirth_interval_s(1.0) == 60.0
    conflict = guard.conflict
    assert conflict is not None and conflict.count == 2 and conflict.since == 1.7e9

    clock.now += guard.hold_s + 1
    assert not guard.active and guard.conflict is None and guard.reconnect_floor_s() == 0.0
    assert guard.count == 2  # the metric is a counter: it never goes down
    assert any("identity conflict over" in r.getMessage() for r in caplog.records)


def test_an_ndeath_with_a_bdseq_we_never_used_is_a_conflict(
        guard: IdentityGuard, caplog: pytest.LogCaptureFixture) -> None:
    guard.used_bdseq(3)
    guard.ndeath_seen(9, 3)
    (line,) = errors(caplog)
    assert "an NDEATH for this id with bdSeq 9 that this gateway never used (ours 3)" in line


def test_mqtt5_session_taken_over_is_a_conflict_at_once(
        guard: IdentityGuard, caplog: pytest.LogCaptureFixture) -> None:
    guard.session_lost("focas-edge-plant-gw", 30.0, "Session taken over")
    (line,) = errors(caplog)
    assert "client id focas-edge-plant-gw" in line and "Session taken over" in line


def test_three_short_sessions_of_one_client_id_are_a_conflict_long_ones_reset(
        guard: IdentityGuard, caplog: pytest.LogCaptureFixture) -> None:
    guard.session_lost("cid", 0.4, "Unspecified error")
    guard.session_lost("cid", 0.4, "Unspecified error")
    guard.session_lost("cid", guard.hold_s + 5, "Unspecified error")  # a long session: a network blip
    guard.session_lost("cid-json", 0.3, "Unspecified error")  # another connection counts on its own
    guard.session_lost("cid", 0.4, "Unspecified error")
    guard.session_lost("cid", 0.4, "Keep alive timeout")  # the network, not another client: starts over
    guard.session_lost("cid", 0.4, "Unspecified error")
    assert not guard.active and not errors(caplog)
    guard.session_lost("cid", 0.4, "Unspecified error")
    guard.session_lost("cid", 0.5, "Unspecified error")
    (line,) = errors(caplog)
    assert "client id cid 3 times in a row" in line and "last after 0.5 s: Unspecified error" in line
    guard.session_lost("cid", 61.0, "Unspecified error")  # while it lasts, each short session is evidence
    assert guard.count == 2 and len(errors(caplog)) == 1


def test_bdseq_of_reads_an_ndeath_and_survives_junk() -> None:
    assert bdseq_of(pl.bdseq_payload(17, 0)) == 17
    assert bdseq_of(b"\xff\xff not protobuf") is None
