"""The replay's fast paths pinned byte for byte to what they replaced (replaycost, 2026-11-26).

`SparkplugNode._historical` writes a float of a Double metric as its parts (no value writer, no
concatenation) and copies the live quality bookkeeping only when it is not empty; `spool_rows._parse`
reads a spool body with json's C scanner instead of json.loads. `old_historical` below is the encoder as it
was before, kept here as the reference; json.loads is the parse's.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from operator import itemgetter
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from edge.publish import ddata as dd
from edge.publish.device_table import DeviceTable
from edge.publish.node import SparkplugNode
from edge.publish.spool_rows import SpoolEntry, _parse, encode_samples
from edge.samples import MetricSpec, MetricType, Quality, Sample
from tests.unit.publish.test_ddata import NAMES, TYPE_OF, make_node, samples

_row_timestamp = itemgetter(3)


def old_historical(node: SparkplugNode, dev: DeviceTable, rows: Sequence[Sequence[Any]]) -> bytes:
    """SparkplugNode._historical as of ea58061 (the payload; it takes a seq as the node does)."""
    parts = [dd.payload_head(node._clock())]
    append = parts.append
    headers = dd.SHORT_RECORD_HEADERS
    historical = dd.HISTORICAL
    slots, alias_data, alias_ends = dev.layout.slots, dev.alias_data, dev.alias_ends
    not_good = set(dev.not_good)
    good = int(Quality.GOOD)
    last_ts = -1
    stamp = b""
    for name, value, _, ts, quality in sorted(rows, key=_row_timestamp):
        position, value_field, mtype = slots[name]
        alias = alias_data[alias_ends[position]:alias_ends[position + 1]]
        if ts != last_ts:
            last_ts = ts
            stamp = dd.timestamp_field(ts) + historical
        if quality == good and value is not None and (not not_good or name not in not_good) \
                and (data := value_field(value)) is not None:
            body = alias + stamp + data
            try:
                append(headers[len(body)] + body)
            except IndexError:
                append(dd.metric_record(body))
            continue
        sample = Sample(name, value, mtype, ts, Quality(quality), True)
        append(node._metric(sample, alias + stamp[:-len(historical)], value_field, mtype, not_good))
    append(dd.payload_tail(node._next_seq()))
    return b"".join(parts)


texts = st.one_of(st.text(max_size=12), st.sampled_from(["Überlast", "温度 MEM", "é" * 70, "\u2603" * 50, ""]))
row_values = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.integers(-300, 70_000),
                       st.floats(), st.floats(width=32), st.just(3.5e38), texts)
rows_of = st.lists(st.tuples(st.sampled_from(NAMES), row_values, st.integers(0, 2**45),
                             st.sampled_from([int(q) for q in Quality])), max_size=10)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(st.booleans(), rows_of), min_size=1, max_size=6))
def test_historical_rows_bytes_equal_the_old_encoder(batches: list[tuple[bool, list[tuple[Any, ...]]]]) -> None:
    """Every metric type, text beyond ASCII and long (a record of 128 bytes or more), nulls, every quality,
    values the fast writers hand to the runtime or the runtime refuses; live batches in between, so the
    live quality bookkeeping the replay starts from is empty or not. Same bytes, same seq, same errors."""
    new, old = make_node(), make_node()
    for n in (new, old):
        n.births()
        n.device_online("m1", [MetricSpec(name, TYPE_OF[name]) for name in NAMES], [])
    for live, batch in batches:
        if live:  # the live path changes `not_good` on both nodes alike
            ss = [Sample(name, value, TYPE_OF[name], ts, Quality(q)) for name, value, ts, q in batch]
            assert new.device_data("m1", ss) == old.device_data("m1", ss)
            continue
        body = encode_samples([Sample(name, value, TYPE_OF[name], ts, Quality(q), True)
                               for name, value, ts, q in batch])
        rows = json.loads(body)
        got = new.historical_rows("m1", rows)
        if not rows:
            assert got == []
            continue
        expected = old_historical(old, old._devices["m1"], rows)
        assert [m.payload for m in got] == [expected]
        assert new.encode_errors == old.encode_errors
        assert new._devices["m1"].not_good == old._devices["m1"].not_good  # a replay leaves it alone


def test_each_metric_type_goes_the_fast_way_and_matches() -> None:
    """One GOOD value of each type (the double as its parts, the rest through their writers), then the
    same after a live BAD value of each (every one through `_metric`, Quality GOOD again)."""
    by_type = {
        MetricType.BOOLEAN: True, MetricType.INT8: -5, MetricType.INT16: 300, MetricType.INT32: -(2**31),
        MetricType.INT64: -(2**40), MetricType.UINT8: 200, MetricType.UINT16: 65535, MetricType.UINT32: 2**32 - 1,
        MetricType.UINT64: 2**64 - 1, MetricType.FLOAT: 0.25, MetricType.DOUBLE: 1.5e300,
        MetricType.STRING: "Überlast 温度", MetricType.DATETIME: 1_790_000_000_000,
    }
    names = {t: f"M/{t.value}" for t in by_type}
    rows = [[names[t], v, t.value, 1_790_000_000_000 + i % 3, 192] for i, (t, v) in enumerate(by_type.items())]
    new, old = make_node(), make_node()
    for n in (new, old):
        n.births()
        n.device_online("m1", [MetricSpec(name, TYPE_OF[name]) for name in NAMES], [])
    for _ in range(2):
        (got,) = new.historical_rows("m1", json.loads(json.dumps(rows)))
        assert got.payload == old_historical(old, old._devices["m1"], json.loads(json.dumps(rows)))
        bad = [Sample(names[t], None, t, 5, Quality.BAD) for t in by_type]
        new.device_data("m1", bad)
        old.device_data("m1", bad)


bodies = st.one_of(
    st.builds(lambda batch: encode_samples(batch), st.lists(samples, max_size=6)),
    st.sampled_from([b"[]", b"[[]]", b"[[\"a\",1.0,\"Double\",5,192]] ", b" [[\"a\",1,\"Int8\",5,192]]",
                     b"[[\"a\",1,\"Int8\",5,192]]x", b"[[\"a\",NaN,\"Double\",5,192]]",
                     b"[[\"a\",1e999,\"Double\",5,192]]",
                     b"[[\"\\u00dc\\ud800\",1,\"Int8\",5,192]]", "[[\"\u00dc\",1,\"String\",5,192]]".encode(),
                     b"[[\"a\",1,\"Int8\",5,192]", b"[[", b"", b"\xef\xbb\xbf[[\"a\",1,\"Int8\",5,192]]",
                     b"[[\"\xff\",1,\"Int8\",5,192]]", "[[\"a\"]]".encode("utf-16-le"), b"[[1,2,3,4,5],{}]"]),
    st.binary(max_size=40).map(lambda b: b"[[" + b),
)


def _loads_or_error(body: bytes) -> object:
    try:
        return ("value", json.loads(body))
    except (ValueError, UnicodeDecodeError) as exc:
        return ("error", type(exc))


def _parse_or_error(body: bytes) -> object:
    try:
        return ("value", _parse(body))
    except (ValueError, UnicodeDecodeError) as exc:
        return ("error", type(exc))


@settings(max_examples=400, deadline=None)
@given(bodies)
def test_parse_is_json_loads(body: bytes) -> None:
    """The row parse's value (repr: NaN stays NaN) or error class is json.loads' own; so are `rows()`."""
    assert repr(_parse_or_error(body)) == repr(_loads_or_error(body))
    entry = SpoolEntry(1, "sparkplug", "m1", "data", body=body)
    loaded = _loads_or_error(body)
    rows = loaded[1] if loaded[0] == "value" else None  # type: ignore[index]
    shaped = type(rows) is list and all(type(r) is list and len(r) == 5 for r in rows)
    assert repr(entry.rows()) == repr(rows if shaped else None)
