"""edge.collect.clock_feed: what a CNC clock answer turns into (the Clock/* samples of a tick)."""

from __future__ import annotations

from datetime import datetime, timedelta
from zoneinfo import ZoneInfo

from edge.collect.changes import ChangeDetector
from edge.collect.clock_feed import ClockFeed
from edge.samples import Sample

T0 = 1_790_000_000.0  # gateway wall time at monotonic 0


def clock_samples(seconds: int, detector: ChangeDetector, feed: ClockFeed, start: int = 0,
                  new_detector_at: int | None = None) -> list[list[Sample]]:
    """Feed one CNC clock second a tick (a 1 Hz poll, 0.3 s into each second) and collect each tick's samples."""
    cnc = datetime(2026, 11, 26, 6, 0, 0)
    out = []
    for s in range(start, start + seconds):
        if s == new_detector_at:
            detector.reset()
            feed.new_session()
        mono = s + 0.3
        feed.observe(cnc + timedelta(seconds=s), mono, T0 + mono, 0.0005)
        samples: list[Sample] = []
        feed.samples(int((T0 + mono) * 1000), mono, detector.report, samples)
        out.append(samples)
    return out


def test_each_change_is_published_once_and_a_new_session_publishes_every_clock_metric_again() -> None:
    feed, detector = ClockFeed("m1", ZoneInfo("UTC"), 2.0), ChangeDetector()
    ticks = clock_samples(40, detector, feed, new_detector_at=25)
    names = {"Clock/Skew", "Clock/UsingGatewayTime", "Clock/OffsetUncertainty", "Clock/Synchronised"}
    assert {s.name for s in ticks[0]} == names  # the first tick: every one
    assert {s.name for s in ticks[25]} == names  # the first tick of a new session: every one again
    published: dict[str, object] = {}
    for tick in ticks[1:25]:  # in between: only values that differ from the last published one
        for sample in tick:
            assert published.get(sample.name, object()) != sample.value
            published[sample.name] = sample.value
    assert sum(map(len, ticks[1:25])) < 24  # most seconds move none of them


def test_the_published_clock_metrics_are_what_offering_every_value_each_tick_publishes() -> None:
    # The same readings through a feed whose values are always offered (its memory of the last offer wiped
    # every tick) publish the same samples.
    feed, detector = ClockFeed("m1", ZoneInfo("Europe/Berlin"), 2.0), ChangeDetector()
    every, every_detector = ClockFeed("m1", ZoneInfo("Europe/Berlin"), 2.0), ChangeDetector()
    cnc = datetime(2026, 11, 26, 7, 0, 0)  # Berlin wall time, an hour ahead of UTC in November
    for s in range(200):
        mono = s * 0.37
        wall = cnc + timedelta(seconds=int(mono + 0.8))
        a: list[Sample] = []
        b: list[Sample] = []
        for f, d, out in ((feed, detector, a), (every, every_detector, b)):
            if f.observe(wall, mono, T0 + mono, 0.0004 + (s % 7) * 0.001) or f.news:
                f.samples(s, mono, d.report, out)
        every._offered = None
        assert a == b
