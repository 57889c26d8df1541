"""A poller's counters: the cycle-time histogram stays a constant size and feeds /metrics."""

from __future__ import annotations


def test_cycle_times_kept_as_a_constant_size_histogram() -> None:
    from edge.collect.stats import CYCLE_BUCKETS, PollerStats
    from edge.service.status_http import cycle_histogram

    stats = PollerStats()
    for seconds in (0.001, 0.005, 0.0051, 0.3, 9.0) * 1000:  # a bound itself counts as "le" that bound
        stats.record_cycle(seconds)
    assert len(stats.cycle_buckets) == len(CYCLE_BUCKETS) + 1
    cumulative = dict(cycle_histogram(stats.cycle_buckets))
    assert (cumulative["0.005"], cumulative["0.01"], cumulative["0.5"], cumulative["+Inf"]) == (2000, 3000, 4000, 5000)
    assert abs(stats.cycle_total_s - 1000 * (0.001 + 0.005 + 0.0051 + 0.3 + 9.0)) < 1e-6
