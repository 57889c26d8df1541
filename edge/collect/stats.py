"""A poller's counters: what the daemon publishes as node metrics, on /metrics and on the status page."""

from __future__ import annotations

from bisect import bisect_left
from dataclasses import dataclass, field

from edge.focas.errors import FocasError

# Poll cycle wall time buckets (seconds): a LAN round trip is ~1-20 ms, a slow control 100 ms+.
CYCLE_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)


@dataclass
class PollerStats:
    """Counters the daemon publishes as node metrics and on /metrics."""

    ticks: int = 0
    status_reads: int = 0  # ticks that read the status group (the status page's achieved poll rate)
    overruns: int = 0
    skipped: int = 0
    connects: int = 0
    disconnects: int = 0
    item_errors: dict[str, int] = field(default_factory=dict)  # by EW name or error class
    last_cycle_s: float = 0.0
    # Cycle wall times as a histogram (counts per CYCLE_BUCKETS bound, then over the last): constant memory
    # per machine, and nothing lost between two scrapes of /metrics.
    cycle_buckets: list[int] = field(default_factory=lambda: [0] * (len(CYCLE_BUCKETS) + 1))
    cycle_total_s: float = 0.0

    def count_error(self, error: FocasError) -> None:
        key = getattr(error, "name", None) or type(error).__name__
        self.item_errors[key] = self.item_errors.get(key, 0) + 1

    def record_cycle(self, seconds: float) -> None:
        self.last_cycle_s = seconds
        self.cycle_buckets[bisect_left(CYCLE_BUCKETS, seconds)] += 1  # first bound >= seconds: "le"
        self.cycle_total_s += seconds
