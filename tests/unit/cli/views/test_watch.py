"""The `watch` decoder: births teach it aliases, data prints with names, anything undecodable survives."""

from __future__ import annotations

import json
from datetime import UTC, datetime

from hypothesis import given
from hypothesis import strategies as st

from edge.cli.views.watch import SparkplugDecoder, json_lines
from edge.publish import payload as pl
from edge.publish.sparkplug_b_pb2 import Payload
from edge.samples import MetricType, Quality

TS = int(datetime(2026, 3, 1, 12, 30, 45, 250_000, tzinfo=UTC).timestamp() * 1000)
DBIRTH = "spBv1.0/plant/DBIRTH/gw/mill-1"
DDATA = "spBv1.0/plant/DDATA/gw/mill-1"


def birth(seq: int = 1) -> bytes:
    p = Payload(timestamp=TS, seq=seq)
    pl.add_birth_metric(p.metrics, "Status/Run", 7, MetricType.STRING, "START", TS)
    pl.add_birth_metric(p.metrics, "Spindle/1/Speed", 8, MetricType.DOUBLE, 1200.0, TS, unit="min-1")
    pl.add_birth_metric(p.metrics, "Macro/500", 9, MetricType.DOUBLE, None, TS, quality=Quality.BAD)
    return p.SerializeToString()


def data(seq: int, *values: tuple[int, MetricType, object]) -> bytes:
    p = Payload(timestamp=TS, seq=seq)
    for alias, mtype, value in values:
        pl.append_data_metric(p.metrics, alias, mtype, TS, value)
    return p.SerializeToString()


def test_data_after_a_birth_prints_names_values_and_cnc_time() -> None:
    decoder = SparkplugDecoder()
    lines = decoder.lines(DBIRTH, birth())
    assert lines[0] == "DBIRTH gw/mill-1 seq=1 (3 metrics)"
    assert "  Macro/500 = (none) [BAD] @12:30:45.250" in lines
    out = decoder.lines(DDATA, data(2, (8, MetricType.DOUBLE, 1234.5), (7, MetricType.STRING, "STOP")))
    assert out == ["DDATA  gw/mill-1 seq=2  Spindle/1/Speed = 1234.5 @12:30:45.250",
                   "DDATA  gw/mill-1 seq=2  Status/Run = STOP @12:30:45.250"]


def test_unknown_alias_is_shown_as_such_and_a_rebirth_replaces_the_map() -> None:
    decoder = SparkplugDecoder()
    assert decoder.lines(DDATA, data(3, (99, MetricType.STRING, "x"))) == \
        ["DDATA  gw/mill-1 seq=3  alias 99 = x @12:30:45.250"]
    decoder.lines(DBIRTH, birth())
    rebirth = Payload(timestamp=TS, seq=0)
    pl.add_birth_metric(rebirth.metrics, "Status/Mode", 7, MetricType.STRING, "MDI", TS)
    decoder.lines(DBIRTH, rebirth.SerializeToString())
    assert decoder.lines(DDATA, data(1, (8, MetricType.STRING, "?")))[0].endswith("alias 8 = ? @12:30:45.250"), \
        "aliases of the previous birth are forgotten"
    assert "Status/Mode = AUTO" in decoder.lines(DDATA, data(2, (7, MetricType.STRING, "AUTO")))[0]


def test_aliases_are_kept_per_device() -> None:
    decoder = SparkplugDecoder()
    decoder.lines(DBIRTH, birth())
    other = "spBv1.0/plant/DDATA/gw/mill-2"
    assert "alias 7" in decoder.lines(other, data(2, (7, MetricType.STRING, "START")))[0]


def test_deaths_state_and_foreign_topics() -> None:
    decoder = SparkplugDecoder()
    ndeath = pl.bdseq_payload(4, TS)
    assert decoder.lines("spBv1.0/plant/NDEATH/gw", ndeath) == ["NDEATH gw"]
    ddeath = Payload(timestamp=TS, seq=9).SerializeToString()
    assert decoder.lines("spBv1.0/plant/DDEATH/gw/mill-1", ddeath) == ["DDEATH gw/mill-1 seq=9"]
    state = json.dumps({"online": True, "timestamp": TS}).encode()
    assert decoder.lines("spBv1.0/STATE/scada", state)[0].startswith("STATE  host=scada {")
    assert decoder.lines("other/topic/a/b", b"x") == []


def test_undecodable_payload_is_reported_not_raised() -> None:
    (line,) = SparkplugDecoder().lines(DDATA, b"\xff\xff\xff")
    assert line.startswith("DDATA  gw/mill-1: undecodable payload")


def test_json_lines() -> None:
    doc = {"value": 12.5, "quality": "GOOD", "ts": TS, "iso": "2026-03-01T12:30:45.250Z"}
    assert json_lines("focas/mill-1/state/Macro/500", json.dumps(doc).encode()) == \
        ["JSON   focas/mill-1/state/Macro/500 = 12.5 @12:30:45.250"]
    bad = {"value": None, "quality": "BAD", "ts": TS}
    assert json_lines("focas/m/state/X", json.dumps(bad).encode())[0].endswith("= (none) [BAD] @12:30:45.250")
    assert json_lines("focas/m/online", b"online") == ["JSON   focas/m/online online"]
    long = json.dumps({"event": "raise", "alarms": list(range(200))}).encode()
    (line,) = json_lines("focas/m/events/alarm", long)
    assert len(line) < 260


metric_values = st.one_of(
    st.tuples(st.just(MetricType.INT32), st.integers(-(2**31), 2**31 - 1)),
    st.tuples(st.just(MetricType.UINT32), st.integers(0, 2**32 - 1)),
    st.tuples(st.just(MetricType.INT64), st.integers(-(2**63), 2**63 - 1)),
    st.tuples(st.just(MetricType.BOOLEAN), st.booleans()),
    st.tuples(st.just(MetricType.STRING), st.text(max_size=40).filter(lambda s: "\n" not in s)),
)


@given(st.lists(metric_values, min_size=1, max_size=8))
def test_property_every_birth_value_round_trips_into_its_data_line(values: list[tuple[MetricType, object]]) -> None:
    decoder = SparkplugDecoder()
    p = Payload(timestamp=TS, seq=0)
    for index, (mtype, value) in enumerate(values):
        pl.add_birth_metric(p.metrics, f"M/{index}", index + 1, mtype, value, TS)
    decoder.lines(DBIRTH, p.SerializeToString())
    lines = decoder.lines(DDATA, data(1, *((i + 1, mtype, value) for i, (mtype, value) in enumerate(values))))
    assert len(lines) == len(values)
    for index, ((_, value), line) in enumerate(zip(values, lines, strict=True)):
        text = str(value) if value != "" else "(none)"
        shown = text if len(text) <= 60 else text[:57] + "..."
        assert line == f"DDATA  gw/mill-1 seq=1  M/{index} = {shown} @12:30:45.250"


@given(st.binary(max_size=200), st.sampled_from(["NBIRTH", "DBIRTH", "NDATA", "DDATA", "DDEATH", "NCMD"]))
def test_property_decoder_never_raises(raw: bytes, kind: str) -> None:
    lines = SparkplugDecoder().lines(f"spBv1.0/g/{kind}/n/d", raw)
    assert all(isinstance(line, str) for line in lines)


def test_an_empty_value_shows_as_none_not_as_nothing() -> None:
    decoder = SparkplugDecoder()
    decoder.lines(DBIRTH, birth())
    out = decoder.lines(DDATA, data(2, (7, MetricType.STRING, "")))
    assert out == ["DDATA  gw/mill-1 seq=2  Status/Run = (none) @12:30:45.250"]
    empty = {"value": "", "quality": "GOOD", "ts": TS}
    assert json_lines("focas/m/state/Program/Comment", json.dumps(empty).encode()) == \
        ["JSON   focas/m/state/Program/Comment = (none) @12:30:45.250"]
