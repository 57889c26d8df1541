from __future__ import annotations

import dataclasses
import math
import pickle

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.collect.changes import ChangeDetector, values_differ
from edge.samples import MetricType, Quality, Sample, new_sample


def s(name: str, value: object, quality: Quality = Quality.GOOD, t: int = 0,
      kind: MetricType = MetricType.DOUBLE) -> Sample:
    return Sample(name, value, kind, t, quality)


def test_first_value_is_reported_then_only_changes() -> None:
    detector = ChangeDetector()
    assert detector.filter([s("a", 1.0), s("b", 2.0)]) == [s("a", 1.0), s("b", 2.0)]
    assert detector.filter([s("a", 1.0, t=5), s("b", 2.5, t=5)]) == [s("b", 2.5, t=5)]


def test_deadband_is_measured_from_the_last_reported_value() -> None:
    detector = ChangeDetector({"x": 0.5})
    assert detector.offer(s("x", 10.0))
    assert not detector.offer(s("x", 10.3))
    assert not detector.offer(s("x", 10.5))  # exactly the deadband: not beyond it
    assert detector.offer(s("x", 10.6))  # drift adds up against 10.0
    assert not detector.offer(s("x", 10.2))
    assert detector.offer(s("x", 10.0))


def test_set_deadband_rejects_negative() -> None:
    detector = ChangeDetector()
    try:
        detector.set_deadband("x", -1)
    except ValueError as exc:
        assert "x" in str(exc)
    else:
        raise AssertionError("negative deadband accepted")


def test_reset_gives_full_state_again() -> None:
    detector = ChangeDetector()
    detector.filter([s("a", 1.0), s("b", "text", kind=MetricType.STRING)])
    assert detector.filter([s("a", 1.0), s("b", "text", kind=MetricType.STRING)]) == []
    detector.reset()
    assert len(detector.filter([s("a", 1.0), s("b", "text", kind=MetricType.STRING)])) == 2


def test_quality_change_is_a_change() -> None:
    detector = ChangeDetector({"a": 100.0})
    detector.offer(s("a", 1.0))
    assert detector.offer(s("a", 1.0, Quality.BAD))
    assert not detector.offer(s("a", 1.0, Quality.BAD))
    assert detector.offer(s("a", 1.0, Quality.GOOD))


def test_nan_and_none() -> None:
    detector = ChangeDetector({"a": 1.0})
    assert detector.offer(s("a", math.nan))
    assert not detector.offer(s("a", math.nan))
    assert detector.offer(s("a", 0.0))
    assert detector.offer(s("a", None))
    assert not detector.offer(s("a", None))
    assert detector.offer(s("a", 0.0))


def test_booleans_and_strings_ignore_deadband() -> None:
    assert values_differ(True, False, 10.0)
    assert not values_differ(True, True, 10.0)
    assert values_differ("a", "b", 10.0)
    assert values_differ(1, True)  # a type change is a change
    assert values_differ([1, 2], [1, 3])


def test_last_reported_is_the_published_picture() -> None:
    detector = ChangeDetector({"a": 1.0})
    detector.offer(s("a", 1.0, t=1))
    detector.offer(s("a", 1.5, t=2))
    assert detector.last_reported()["a"] == s("a", 1.0, t=1)


@given(st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=50), st.floats(0, 100))
def test_reported_values_track_within_deadband(values: list[float], deadband: float) -> None:
    """Whatever the sequence, the last reported value is never more than the deadband off the latest."""
    detector = ChangeDetector({"x": deadband})
    for value in values:
        detector.offer(s("x", value))
        reported = detector.last_reported()["x"].value
        assert isinstance(reported, float)
        assert abs(reported - value) <= deadband


_values = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5),
                    st.booleans(), st.sampled_from(["a", "b"]), st.sampled_from([0.0, 1.0, 1.5, -1.5]))
_offers = st.lists(st.tuples(st.sampled_from(["p", "q"]), _values, st.sampled_from(list(Quality)),
                             st.sampled_from([MetricType.DOUBLE, MetricType.INT32, MetricType.STRING])),
                   max_size=40)


@given(_offers, st.sampled_from([0.0, 0.5]))
def test_property_report_decides_exactly_as_offer(offers: list[tuple[str, object, Quality, MetricType]],
                                                 band: float) -> None:
    """The poll tick's single-pass report() must publish exactly what offer() would."""
    by_offer, by_report = ChangeDetector({"p": band}), ChangeDetector({"p": band})
    for t, (name, value, quality, kind) in enumerate(offers):
        offered = by_offer.offer(Sample(name, value, kind, t, quality))
        reported = by_report.report(name, value, kind, t, quality)
        assert offered == (reported is not None)
        assert reported is None or reported == Sample(name, value, kind, t, quality)
    assert by_offer.last_reported() == by_report.last_reported()


def test_the_change_detectors_samples_are_the_samples_the_constructor_builds() -> None:
    built = new_sample("Axis/X/Absolute", 1.5, MetricType.DOUBLE, 1_700_000_000_123, Quality.BAD)
    assert built == Sample("Axis/X/Absolute", 1.5, MetricType.DOUBLE, 1_700_000_000_123, Quality.BAD)
    assert type(built) is Sample and built.historical is False
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.value = 2.0  # type: ignore[misc]


def test_a_reported_sample_is_a_sample_in_every_way_the_constructor_builds_one() -> None:
    """report() fills a SampleDraft and gives it Sample's class: equal, equally hashed, frozen, and it pickles."""
    reported = ChangeDetector().report("Macro/500", 2.5, MetricType.DOUBLE, 1_700_000_000_123)
    built = Sample("Macro/500", 2.5, MetricType.DOUBLE, 1_700_000_000_123)
    assert type(reported) is Sample and reported == built and hash(reported) == hash(built)
    assert pickle.loads(pickle.dumps(reported)) == built and repr(reported) == repr(built)
    with pytest.raises(dataclasses.FrozenInstanceError):
        reported.value = 3.0  # type: ignore[misc]


@given(_offers, st.sampled_from([0.0, 0.5]))
def test_property_declared_names_change_nothing_but_where_samples_are_kept(
        offers: list[tuple[str, object, Quality, MetricType]], band: float) -> None:
    """Samples kept by position ("q" declared, its index shared) or not ("p") decide and remember as before."""
    undeclared, declared = ChangeDetector({"p": band}), ChangeDetector({"p": band}, names=["q", "q"])
    other = ChangeDetector(names=["q", "q"])
    for t, (name, value, quality, kind) in enumerate(offers):
        if t == len(offers) // 2:
            for detector in (undeclared, declared):
                detector.forget("p")
                detector.forget("q")
        expected = undeclared.report(name, value, kind, t, quality)
        assert declared.report(name, value, kind, t, quality) == expected
    assert declared.last_reported() == undeclared.last_reported()
    assert other.last_reported() == {}  # the index is shared, the samples are not
    declared.reset()
    assert declared.last_reported() == {}
    if offers:
        name, value, quality, kind = offers[0]
        assert declared.offer(Sample(name, value, kind, 0, quality))  # after reset: reported again


def test_declared_metrics_come_first_in_the_picture_then_the_others_as_first_reported() -> None:
    detector = ChangeDetector(names=["b", "a"])
    detector.filter([s("z", 1.0), s("a", 1.0), s("y", 1.0), s("b", 1.0)])
    assert list(detector.last_reported()) == ["b", "a", "z", "y"]
