"""DATA payloads written by hand (edge.publish.ddata) are byte for byte what the protobuf runtime writes.

The reference below is the straightforward runtime encoding the node used before: one `metrics.add` per
metric, Quality as a property, then SerializeToString. Hypothesis drives both with the same samples,
including values the fast writers hand back to the runtime (wrong Python type, out of range, float32
overflow, text that is not UTF-8) and values the runtime refuses (counted as encode errors, sent null+BAD).
"""

from __future__ import annotations

import json
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from edge.publish import ddata as dd
from edge.publish import payload as pl
from edge.publish.aliases import AliasMap
from edge.publish.node import SparkplugNode
from edge.publish.sparkplug_b_pb2 import Payload
from edge.publish.spool_rows import decode_samples, encode_samples
from edge.samples import MetricSpec, MetricType, Quality, Sample

CLOCK_MS = 1_700_000_000_123
TYPES = list(MetricType)
NAMES = [f"M/{t.value}" for t in TYPES] + [f"N/{t.value}" for t in TYPES]
TYPE_OF = {name: TYPES[i % len(TYPES)] for i, name in enumerate(NAMES)}

values = st.one_of(
    st.none(), st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.integers(min_value=-300, max_value=70_000),
    st.floats(allow_nan=False), st.floats(width=32), st.just(3.5e38), st.just(1e300),
    st.text(max_size=12), st.just("\udcff"), st.lists(st.integers(0, 9), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(0, 9), max_size=2),
)


def make_node() -> SparkplugNode:
    n = SparkplugNode("G", "E", AliasMap(None), clock=lambda: CLOCK_MS)
    n.session_started(3)
    return n


samples = st.builds(
    lambda name, value, ts, quality, historical: Sample(name, value, TYPE_OF[name], ts, quality, historical),
    st.sampled_from(NAMES), values, st.integers(0, 2**45), st.sampled_from(list(Quality)), st.booleans())


def reference(seq: int, aliases: dict[str, int], batch: list[Sample], not_good: set[str]) -> tuple[bytes, int]:
    """The runtime encoding of one DATA message; returns (bytes, encode errors)."""
    p = Payload(timestamp=CLOCK_MS, seq=seq)
    errors = 0
    for s in sorted(batch, key=lambda s: s.timestamp_ms):
        alias = aliases[s.name]
        try:
            if s.value is None:
                m = p.metrics.add(alias=alias, timestamp=s.timestamp_ms, is_null=True)
            else:
                m = pl.DATA_WRITERS[s.type](p.metrics, alias, s.timestamp_ms, s.value)
        except (TypeError, ValueError, OverflowError):
            errors += 1
            m = p.metrics.add(alias=alias, timestamp=s.timestamp_ms, is_null=True)
            pl.add_quality(m, Quality.BAD)
            not_good.add(s.name)
            continue
        if s.historical:
            m.is_historical = True
        if s.quality is not Quality.GOOD:
            pl.add_quality(m, s.quality)
            not_good.add(s.name)
        elif s.name in not_good:
            pl.add_quality(m, Quality.GOOD)
            not_good.discard(s.name)
    return p.SerializeToString(), errors


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(samples, max_size=8), min_size=1, max_size=6))
def test_device_data_bytes_equal_the_runtime_encoding(batches: list[list[Sample]]) -> None:
    n = make_node()
    n.births()
    n.device_online("m1", [MetricSpec(name, TYPE_OF[name]) for name in NAMES], [])
    aliases = {name: n._aliases.alias("m1", name) for name in NAMES}
    not_good: set[str] = set()
    errors = 0
    for batch in batches:
        out = n.device_data("m1", batch)
        if not batch:
            assert out == []
            continue
        seq = Payload.FromString(out[0].payload).seq
        expected, failed = reference(seq, aliases, batch, not_good)
        errors += failed
        assert out[0].payload == expected
        assert n.encode_errors == errors


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.lists(samples, max_size=8)), min_size=1, max_size=6))
def test_historical_data_bytes_equal_the_runtime_encoding(batches: list[tuple[bool, list[Sample]]]) -> None:
    """Replayed batches (their own loop in the node) between live ones: every metric is_historical, and the
    live quality bookkeeping is what the live batches alone make it."""
    n = make_node()
    n.births()
    n.device_online("m1", [MetricSpec(name, TYPE_OF[name]) for name in NAMES], [])
    aliases = {name: n._aliases.alias("m1", name) for name in NAMES}
    not_good: set[str] = set()
    for replayed, batch in batches:
        out = n.historical_data("m1", batch) if replayed else n.device_data("m1", batch)
        if not batch:
            assert out == []
            continue
        seq = Payload.FromString(out[0].payload).seq
        if replayed:
            marked = [Sample(s.name, s.value, s.type, s.timestamp_ms, s.quality, True) for s in batch]
            expected, _ = reference(seq, aliases, marked, set(not_good))
        else:
            expected, _ = reference(seq, aliases, batch, not_good)
        assert out[0].payload == expected


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(samples, max_size=8), min_size=1, max_size=4))
def test_historical_rows_bytes_equal_historical_data_of_their_samples(batches: list[list[Sample]]) -> None:
    """The replay's parsed spool rows, encoded without samples, give the bytes their samples give."""
    by_rows, by_samples = make_node(), make_node()
    for n in (by_rows, by_samples):
        n.births()
        n.device_online("m1", [MetricSpec(name, TYPE_OF[name]) for name in NAMES[:-2]], [])
    for batch in batches:
        body = encode_samples(batch)
        rows = json.loads(body)
        expected = by_samples.historical_data("m1", decode_samples(body, historical=True))
        assert by_rows.historical_rows("m1", rows) == expected
    assert by_rows.unknown_metrics == by_samples.unknown_metrics
    assert by_rows.encode_errors == by_samples.encode_errors


def test_a_row_the_fast_path_cannot_read_raises_and_takes_no_seq() -> None:
    n = make_node()
    n.births()
    n.device_online("m1", [MetricSpec("a", MetricType.DOUBLE)], [])
    for bad in ([["a", 1.0, "Double", 5, 7]], [["a", 1.0, "Double", "5", 192]]):
        try:
            n.historical_rows("m1", bad)
        except (TypeError, ValueError):
            pass
        else:
            raise AssertionError(f"{bad} was encoded")
    (out,) = n.historical_rows("m1", [["a", 1.0, "Double", 5, 192]])
    assert Payload.FromString(out.payload).seq == 2, "NBIRTH 0, DBIRTH 1, then this one: no seq lost"


@given(st.one_of(st.integers(0, 2**64 - 1), st.integers(2**35 - 2, 2**42 + 2), st.integers(0, 2**15)))
def test_varint_matches_the_runtime(n: int) -> None:
    assert dd.timestamp_field(n) == Payload.Metric(timestamp=n).SerializeToString()


def test_varint_refuses_what_a_uint64_cannot_hold() -> None:
    for bad in (-1, 2**64):
        try:
            dd.varint(bad)
        except ValueError as exc:
            assert str(bad) in str(exc)
        else:
            raise AssertionError(f"varint({bad}) did not raise")


def test_float32_nan_and_infinities_match_the_runtime() -> None:
    for v in (math.nan, math.inf, -math.inf, -0.0, 1e-46):
        fast = dd.VALUE_FIELDS[MetricType.FLOAT](v)
        assert fast == dd.runtime_value_field(MetricType.FLOAT, v)


def test_historical_null_with_quality_in_field_order() -> None:
    n = make_node()
    n.births()
    n.device_online("m1", [MetricSpec("a", MetricType.DOUBLE)], [])
    out = n.historical_data("m1", [Sample("a", None, MetricType.DOUBLE, 5, Quality.STALE)])
    m = Payload.FromString(out[0].payload).metrics[0]
    assert (m.is_historical, m.is_null, pl.quality_of(m)) == (True, True, Quality.STALE)
    assert m.WhichOneof("value") is None



def test_a_value_the_runtime_overflows_on_is_sent_null_and_bad() -> None:
    n = make_node()
    n.births()
    n.device_online("m1", [MetricSpec("flag", MetricType.BOOLEAN), MetricSpec("x", MetricType.DOUBLE)], [])
    out = n.device_data("m1", [Sample("flag", 2**63, MetricType.BOOLEAN, 5), Sample("x", 1.5, MetricType.DOUBLE, 5)])
    flag, x = Payload.FromString(out[0].payload).metrics
    assert (flag.is_null, pl.quality_of(flag), x.double_value) == (True, Quality.BAD, 1.5)
    assert n.encode_errors == 1
    (rebirth,) = [m for m in n.births() if "/DBIRTH/" in m.topic]
    born = {m.name: m for m in Payload.FromString(rebirth.payload).metrics}
    assert set(born) >= {"flag", "x"}  # births coerce with bool() (VALUE_SETTERS), so nothing raises there
