"""A run of failed connects in the log: one WARNING with the reason, DEBUG repeats, a rare reminder with the
count and since-when, one INFO line when it connects again (edge.focas.outage)."""

from __future__ import annotations

import logging

import pytest

from edge.focas.outage import ConnectOutage, backoff_s, duration_words

LOGGER = logging.getLogger("test.outage")


class Clocks:
    def __init__(self) -> None:
        self.mono = 50.0
        self.wall = 1_800_000_000.0

    def advance(self, seconds: float) -> None:
        self.mono += seconds
        self.wall += seconds


def lines(caplog: pytest.LogCaptureFixture, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOGGER.name and r.levelno == level]


@pytest.mark.parametrize(("seconds", "words"), [
    (12.4, "12 s"), (59, "59 s"), (60, "1 min"), (754, "12 min"), (3 * 3600 + 12 * 60 + 5, "3 h 12 min"),
    (2 * 86400 + 5 * 3600 + 600, "2 d 5 h"),
])
def test_durations_read_as_people_say_them(seconds: float, words: str) -> None:
    assert duration_words(seconds) == words


def test_a_weekend_outage_is_one_warning_rare_reminders_and_one_line_when_it_is_back(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger=LOGGER.name)
    clocks = Clocks()
    outage = ConnectOutage("machine=m1", LOGGER, reminder_every_s=3600, clock=lambda: clocks.mono,
                           wall=lambda: clocks.wall)
    outage.connected()  # the first connect of a run: nothing to say beyond the caller's own line
    assert caplog.records == []
    for _ in range(412):  # 3 h 12 min of retries every 28 s
        outage.failed("connect: [Errno 111] Connection refused", 28.0)
        clocks.advance(28.0)
    warnings = lines(caplog, logging.WARNING)
    assert warnings[0].startswith("connect failed machine=m1 error=connect: [Errno 111] Connection refused")
    assert len(warnings) == 4  # the first, then one an hour (3 h 12 min)
    assert all(w.startswith("still cannot connect machine=m1 down_since=") for w in warnings[1:])
    assert "down_for=1 h 0 min failed_attempts=130 " in warnings[1]
    assert len(lines(caplog, logging.DEBUG)) == 412 - 4
    outage.connected()
    assert lines(caplog, logging.INFO) == [
        f"machine=m1 connected again after 3 h 12 min, 412 failed attempts (down since "
        f"{warnings[1].split('down_since=')[1].split(' ')[0]})"]
    caplog.clear()
    outage.failed("timed out")  # a new run: its first failure is a WARNING again
    assert lines(caplog, logging.WARNING) == [
        "connect failed machine=m1 error=timed out (repeats are logged at DEBUG, a reminder every 1 h 0 min)"]


def test_backoff_is_jittered_below_a_doubling_cap() -> None:
    """Capped exponential backoff with full jitter: after n failures, uniform in [0, min(max, initial * 2**(n-1))]."""
    for failures, cap in ((1, 0.5), (2, 1.0), (3, 2.0), (7, 30.0), (10_000, 30.0)):
        waits = [backoff_s(failures, 0.5, 30.0) for _ in range(400)]
        assert all(0.0 <= w <= cap for w in waits)
        assert max(waits) > 0.75 * cap and min(waits) < 0.25 * cap  # spread over the range, not fixed
