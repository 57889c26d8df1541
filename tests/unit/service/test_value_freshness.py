"""A value's quality and age on the status page: never GOOD from a dead session or a stalled poll."""

from __future__ import annotations

import re

from edge.samples import Quality
from edge.service.value_freshness import STALE_AFTER_PERIODS, freshness, local_iso

NOW = 1_800_000_000.0


def test_a_value_read_within_three_periods_is_good_with_its_age_since_the_last_read() -> None:
    fresh = freshness(Quality.GOOD, online=True, last_read=NOW - 0.7, changed_at=NOW - 3600, period_s=0.25,
                      now=NOW)
    assert fresh.quality == "GOOD"
    assert abs(fresh.age_s - 0.7) < 1e-6  # since the last read, not since the value last changed
    assert fresh.last_good == NOW - 0.7


def test_a_value_older_than_three_poll_periods_is_stale() -> None:
    period = 0.5
    fresh = freshness(Quality.GOOD, online=True, last_read=NOW - STALE_AFTER_PERIODS * period - 0.01,
                      changed_at=NOW - 10, period_s=period, now=NOW)
    assert fresh.quality == "STALE" and fresh.age_s > STALE_AFTER_PERIODS * period


def test_every_value_of_a_machine_whose_session_is_down_is_stale_and_ages() -> None:
    fresh = freshness(Quality.GOOD, online=False, last_read=NOW - 15, changed_at=NOW - 20, period_s=1.0, now=NOW)
    assert (fresh.quality, fresh.age_s, fresh.last_good) == ("STALE", 15.0, NOW - 15)
    static = freshness(Quality.GOOD, online=False, last_read=None, changed_at=NOW - 30, period_s=None, now=NOW)
    assert static.quality == "STALE" and static.age_s == 30.0


def test_a_failed_read_is_bad_since_the_tick_that_reported_it() -> None:
    fresh = freshness(Quality.BAD, online=True, last_read=NOW - 0.1, changed_at=NOW - 12, period_s=1.0, now=NOW)
    assert (fresh.quality, fresh.age_s) == ("BAD", 12.0)


def test_a_static_value_is_never_stale_by_age_while_the_session_is_up() -> None:
    fresh = freshness(Quality.GOOD, online=True, last_read=None, changed_at=NOW - 86400, period_s=None, now=NOW)
    assert fresh.quality == "GOOD" and fresh.age_s == 86400.0


def test_a_cnc_clock_ahead_of_the_gateway_gives_no_negative_age() -> None:
    fresh = freshness(Quality.BAD, online=True, last_read=None, changed_at=NOW + 5, period_s=1.0, now=NOW)
    assert fresh.age_s == 0.0


def test_local_times_carry_their_utc_offset() -> None:
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d", local_iso(NOW))
