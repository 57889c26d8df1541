"""A poller's counters: what the daemon publishes as node metrics, on /metrics and on the status page.

Failed reads are counted per function and EW code, and a function whose reads fail now is kept with since
when, so "the alarm history has failed for two days" is on the page and in /metrics, not only in a log
line once (issue 24).
"""

from __future__ import annotations

from bisect import bisect_left
from collections import Counter
from dataclasses import dataclass, field

from edge.focas.errors import FocasError

# Poll cycle wall time buckets (seconds): a LAN round trip is ~1-20 ms, a slow control 100 ms+.
CYCLE_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)


@dataclass
class FunctionTrouble:
    """A function whose reads fail now: since when (wall time), failures in a row, the last error."""

    since: float
    errors: int
    error: str


@dataclass
class PollerStats:
    """Counters the daemon publishes as node metrics and on /metrics."""

    ticks: int = 0
    status_reads: int = 0  # ticks that read the status group (the status page's achieved poll rate)
    clock_probes: int = 0  # clock-only reads between ticks (edge.collect.clock_probe)
    overruns: int = 0
    skipped: int = 0
    connects: int = 0
    disconnects: int = 0
    errors: dict[tuple[str, str], int] = field(default_factory=dict)  # (function, EW name or class) -> count
    failing: dict[str, FunctionTrouble] = field(default_factory=dict)  # by function, until it answers again
    last_cycle_s: float = 0.0
    # Cycle wall times as a histogram (counts per CYCLE_BUCKETS bound, then over the last): constant memory
    # per machine, and nothing lost between two scrapes of /metrics.
    cycle_buckets: list[int] = field(default_factory=lambda: [0] * (len(CYCLE_BUCKETS) + 1))
    cycle_total_s: float = 0.0

    @property
    def item_errors(self) -> dict[str, int]:
        """Failed reads by EW name or error class, every function together."""
        by_code: Counter[str] = Counter()
        for (_, code), count in self.errors.items():
            by_code[code] += count
        return dict(by_code)

    def count_error(self, function: str, error: FocasError) -> None:
        key = (function, getattr(error, "name", None) or type(error).__name__)
        self.errors[key] = self.errors.get(key, 0) + 1

    def failed(self, function: str, error: FocasError, now: float) -> bool:
        """Note that `function` failed at wall time `now`; True when this failure starts its trouble."""
        trouble = self.failing.get(function)
        if trouble is None:
            self.failing[function] = FunctionTrouble(now, 1, str(error))
            return True
        trouble.errors += 1
        trouble.error = str(error)
        return False

    def answered(self, function: str) -> FunctionTrouble | None:
        """`function` read fine: its trouble (now over), or None when it was not failing."""
        return self.failing.pop(function, None)

    def record_cycle(self, seconds: float) -> None:
        self.last_cycle_s = seconds
        self.cycle_buckets[bisect_left(CYCLE_BUCKETS, seconds)] += 1  # first bound >= seconds: "le"
        self.cycle_total_s += seconds
