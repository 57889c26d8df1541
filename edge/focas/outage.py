"""A run of failed connects said once, reminded now and then, and its end: an outage in the log.

A CNC switched off for the weekend makes its poller retry every backoff_max_s (30 s): one WARNING per
attempt is thousands of lines that bury everything else in the journal. So the first failure of a run is
one WARNING with the reason; repeats are DEBUG; every `reminder_every_s` (15 min) one WARNING says the
outage still lasts, since when and how many attempts failed; and the first connect after a run is one
INFO line saying how long it lasted. The CNC poller, the library host connection and the library host's
own CNC handle all log their outages this way (the MQTT broker: edge.publish.broker_trouble, same policy).
"""

from __future__ import annotations

import logging
import random
import time
from collections.abc import Callable
from datetime import datetime

REMINDER_EVERY_S = 900.0


def duration_words(seconds: float) -> str:
    """45 s, 12 min, 3 h 12 min, 2 d 5 h: how long an outage lasted, for people reading a journal."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    minutes = s // 60
    if minutes < 60:
        return f"{minutes} min"
    hours, minutes = divmod(minutes, 60)
    if hours < 24:
        return f"{hours} h {minutes} min"
    days, hours = divmod(hours, 24)
    return f"{days} d {hours} h"


def backoff_s(failures: int, initial_s: float, max_s: float) -> float:
    """The wait before the next connect attempt after `failures` failed ones in a row: capped exponential
    backoff with full jitter, uniform in [0, min(max_s, initial_s * 2**(failures - 1))] (as tenacity's
    wait_random_exponential, which a plain loop replaces where a session connects: its retry objects
    hold each other, and a cycle that outlives a young collection waits for the hourly full one)."""
    return random.uniform(0.0, min(max_s, initial_s * 2.0 ** min(failures - 1, 64)))


def local_time(epoch_s: float) -> str:
    """A wall time as the plant reads it: local, with its offset, to the second (one word, for key=value)."""
    return datetime.fromtimestamp(epoch_s).astimezone().isoformat(timespec="seconds")


class ConnectOutage:
    """Follows one connection's connect attempts; logs a run of failures at its start, rarely, and its end.

    `subject` is the key=value context that names the connection ("machine=m1", "peer=host:8193").
    """

    def __init__(self, subject: str, logger: logging.Logger, *, reminder_every_s: float = REMINDER_EVERY_S,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time) -> None:
        self.subject = subject
        self._log = logger
        self._reminder_every_s = reminder_every_s
        self._clock = clock
        self._wall = wall
        self.failed_attempts = 0  # in the current run; 0 while connected (or before the first attempt)
        self.down_since = 0.0  # wall time of the run's first failure
        self._started_at = 0.0  # its monotonic twin (durations must not jump with the wall clock)
        self._reminded_at = 0.0

    def failed(self, error: object, retry_in_s: float | None = None) -> None:
        """A connect attempt failed: WARNING for the first of a run, DEBUG after, a WARNING reminder rarely."""
        now = self._clock()
        self.failed_attempts += 1
        retry = "" if retry_in_s is None else f" retry_in={retry_in_s:.2f}s"
        if self.failed_attempts == 1:
            self.down_since = self._wall()
            self._started_at = self._reminded_at = now
            self._log.warning("connect failed %s error=%s%s (repeats are logged at DEBUG, a reminder every %s)",
                              self.subject, error, retry, duration_words(self._reminder_every_s))
        elif now - self._reminded_at >= self._reminder_every_s:
            self._reminded_at = now
            self._log.warning("still cannot connect %s down_since=%s down_for=%s failed_attempts=%d last_error=%s",
                              self.subject, local_time(self.down_since), duration_words(now - self._started_at),
                              self.failed_attempts, error)
        else:
            self._log.debug("connect failed %s attempt=%d error=%s%s", self.subject, self.failed_attempts, error,
                            retry)

    def connected(self) -> None:
        """A connect succeeded: one INFO line if it ends a run of failures; the next failure starts a new run."""
        if self.failed_attempts:
            self._log.info("%s connected again after %s, %d failed attempt%s (down since %s)", self.subject,
                           duration_words(self._clock() - self._started_at), self.failed_attempts,
                           "" if self.failed_attempts == 1 else "s", local_time(self.down_since))
        self.failed_attempts = 0
