"""How old a value is and whether it can still be called GOOD, for status.json and the status page.

A value is reported by exception, so its sample's timestamp says when it last *changed*, not when it was
last read: a spindle speed unchanged for an hour is still fresh. Its age is the time since its poll group
was last read by a batch that answered (MachinePoller.read_at; a failed read has quality BAD and its age
counts from the failure). A value is not GOOD once the machine's session is down, or once it is older
than STALE_AFTER_PERIODS of its group's poll period (a loop that stalled).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

from edge.samples import Quality

STALE_AFTER_PERIODS = 3


def local_iso(epoch_s: float) -> str:
    """Local time with its UTC offset, to the second: 2026-11-25T19:30:05+01:00."""
    return datetime.fromtimestamp(epoch_s).astimezone().isoformat(timespec="seconds")


@dataclass(frozen=True, slots=True)
class Freshness:
    quality: str  # GOOD, STALE or BAD
    age_s: float  # seconds since the last good read
    last_good: float  # wall time (epoch seconds) of the last good read


def freshness(quality: Quality, *, online: bool, last_read: float | None, changed_at: float,
              period_s: float | None, now: float) -> Freshness:
    """The quality and age of one value.

    quality: the sample's own (BAD when its read failed); last_read: when its group was last read (None when
    unknown: a static value); changed_at: the sample's time in epoch seconds (when it was last reported; the
    CNC's clock, so only used when nothing better is known); period_s: its group's poll period (None: read
    once per session, never stale by age). All times are epoch seconds.
    """
    # BAD: since the tick that reported it (the reads before were the last good ones); static: when reported.
    last_good = last_read if quality is Quality.GOOD and last_read is not None else min(changed_at, now)
    age = max(0.0, now - last_good)
    if not online:
        return Freshness(Quality.STALE.name, age, last_good)
    if quality is not Quality.GOOD:
        return Freshness(Quality(quality).name, age, last_good)
    if period_s is not None and age > STALE_AFTER_PERIODS * period_s:
        return Freshness(Quality.STALE.name, age, last_good)
    return Freshness(Quality.GOOD.name, age, last_good)
