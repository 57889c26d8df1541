"""Sparkplug value encoding per shared/docs/sparkplug.md §1.10 (Tahu Java semantics), with round trips."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.publish import payload as pl
from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.samples import MetricType, Quality

RANGES = {
    MetricType.INT8: (-(2**7), 2**7 - 1), MetricType.INT16: (-(2**15), 2**15 - 1),
    MetricType.INT32: (-(2**31), 2**31 - 1), MetricType.INT64: (-(2**63), 2**63 - 1),
    MetricType.UINT8: (0, 2**8 - 1), MetricType.UINT16: (0, 2**16 - 1),
    MetricType.UINT32: (0, 2**32 - 1), MetricType.UINT64: (0, 2**64 - 1),
    MetricType.DATETIME: (0, 2**63 - 1),
}
FIELD = {
    MetricType.INT8: "int_value", MetricType.INT16: "int_value", MetricType.INT32: "int_value",
    MetricType.UINT8: "int_value", MetricType.UINT16: "int_value",
    MetricType.UINT32: "long_value", MetricType.INT64: "long_value", MetricType.UINT64: "long_value",
    MetricType.DATETIME: "long_value", MetricType.FLOAT: "float_value", MetricType.DOUBLE: "double_value",
    MetricType.BOOLEAN: "boolean_value", MetricType.STRING: "string_value",
}


def wire_round_trip(m: Payload.Metric) -> Payload.Metric:
    p = Payload()
    p.metrics.append(m)
    return pl.decode(p.SerializeToString()).metrics[0]


@st.composite
def typed_values(draw: st.DrawFn) -> tuple[MetricType, object]:
    mtype = draw(st.sampled_from(list(MetricType)))
    if mtype in RANGES:
        lo, hi = RANGES[mtype]
        return mtype, draw(st.integers(lo, hi))
    if mtype is MetricType.FLOAT:
        return mtype, draw(st.floats(width=32, allow_nan=False))
    if mtype is MetricType.DOUBLE:
        return mtype, draw(st.floats(allow_nan=False))
    if mtype is MetricType.BOOLEAN:
        return mtype, draw(st.booleans())
    return mtype, draw(st.text())


@given(typed_values(), st.integers(0, 2**63 - 1), st.integers(0, 2**64 - 1))
def test_data_metric_round_trip_in_the_tahu_field(tv: tuple[MetricType, object], ts: int, alias: int) -> None:
    mtype, value = tv
    p = Payload()
    pl.append_data_metric(p.metrics, alias, mtype, ts, value)
    m = pl.decode(p.SerializeToString()).metrics[0]
    assert m.WhichOneof("value") == FIELD[mtype]
    assert not m.HasField("name") and not m.HasField("datatype")
    assert m.alias == alias and m.timestamp == ts
    assert pl.get_value(m, mtype) == value


@given(typed_values())
def test_birth_metric_round_trip(tv: tuple[MetricType, object]) -> None:
    mtype, value = tv
    p = Payload()
    pl.add_birth_metric(p.metrics, "A/B", 7, mtype, value, 5, unit="mm", quality=Quality.STALE)
    m = pl.decode(p.SerializeToString()).metrics[0]
    assert m.name == "A/B" and m.alias == 7 and m.datatype == pl.DATATYPE[mtype] and m.timestamp == 5
    assert pl.get_value(m, mtype) == value
    assert pl.quality_of(m) is Quality.STALE
    assert dict(zip(m.properties.keys, [v.type for v in m.properties.values], strict=True)) == {
        "engUnit": DataType.String, "Quality": DataType.Int32}


@pytest.mark.parametrize(("mtype", "value", "raw"), [
    (MetricType.INT8, -5, 0xFFFFFFFB),  # sign-extended to 32 bits, as Tahu Java (JS reads -5, not 251)
    (MetricType.INT16, -2, 0xFFFFFFFE),
    (MetricType.INT32, -100000, (-100000) & 0xFFFFFFFF),
    (MetricType.UINT16, 65535, 65535),
])
def test_small_ints_in_int_value_sign_extended(mtype: MetricType, value: int, raw: int) -> None:
    m = Payload.Metric()
    pl.set_value(m, mtype, value)
    assert m.WhichOneof("value") == "int_value" and m.int_value == raw


def test_uint32_in_long_value_and_int64_twos_complement() -> None:
    m = Payload.Metric()
    pl.set_value(m, MetricType.UINT32, 4_000_000_000)
    assert m.WhichOneof("value") == "long_value" and m.long_value == 4_000_000_000
    pl.set_value(m, MetricType.INT64, -42)
    assert m.long_value == 2**64 - 42


@given(st.integers(-(2**7), 2**7 - 1))
def test_tolerant_decoding_of_host_variants(v: int) -> None:
    # Hosts may send an Int8 sign-extended to 32 bits (int_value) or to 64 bits (long_value): both decode
    # the same. A form masked to 8 bits is not accepted: 0xFF cannot be told from 255 (see below).
    for field, raw in (("int_value", v & 0xFFFFFFFF), ("long_value", v & 0xFFFFFFFFFFFFFFFF)):
        m = Payload.Metric()
        setattr(m, field, raw)
        assert pl.get_value(wire_round_trip(m), MetricType.INT8) == v


@pytest.mark.parametrize(("mtype", "field", "number"), [
    (MetricType.INT16, "int_value", 70000),  # would land as 4464
    (MetricType.INT16, "int_value", -40000),
    (MetricType.INT16, "long_value", 70000),
    (MetricType.INT16, "int_value", 40000),  # 0x9C40: a masked -25536 or an out-of-range 40000
    (MetricType.INT8, "int_value", 200),
    (MetricType.INT8, "int_value", -129),
    (MetricType.INT32, "long_value", 2**31),
    (MetricType.INT32, "long_value", -(2**31) - 1),
    (MetricType.UINT8, "int_value", -1),
    (MetricType.UINT16, "int_value", -1),
    (MetricType.UINT32, "long_value", -1),
])
def test_integers_outside_their_datatype_are_refused_never_wrapped(mtype: MetricType, field: str,
                                                                   number: int) -> None:
    m = Payload.Metric()
    setattr(m, field, number & (0xFFFFFFFF if field == "int_value" else 0xFFFFFFFFFFFFFFFF))
    with pytest.raises(ValueError, match=str(number)):
        pl.get_value(wire_round_trip(m), mtype)


@pytest.mark.parametrize(("mtype", "number"), [
    (MetricType.INT8, -128), (MetricType.INT8, 127), (MetricType.INT16, -32768), (MetricType.INT16, 32767),
    (MetricType.INT32, -(2**31)), (MetricType.INT32, 2**31 - 1), (MetricType.INT64, -(2**63)),
])
def test_integers_at_their_datatype_limits_decode_in_both_fields(mtype: MetricType, number: int) -> None:
    for field, mask in (("int_value", 0xFFFFFFFF), ("long_value", 0xFFFFFFFFFFFFFFFF)):
        if mtype is MetricType.INT64 and field == "int_value":
            continue
        m = Payload.Metric()
        setattr(m, field, number & mask)
        assert pl.get_value(wire_round_trip(m), mtype) == number


def test_uint32_accepted_from_either_field_and_out_of_range_rejected() -> None:
    assert pl.get_value(Payload.Metric(int_value=7), MetricType.UINT32) == 7
    assert pl.get_value(Payload.Metric(long_value=7), MetricType.UINT32) == 7
    with pytest.raises(ValueError, match="unsigned 32-bit"):
        pl.get_value(Payload.Metric(long_value=2**32), MetricType.UINT32)
    with pytest.raises(ValueError, match="expected string_value"):
        pl.get_value(Payload.Metric(double_value=1.0), MetricType.STRING)


def test_null_and_structured_strings() -> None:
    p = Payload()
    m = pl.append_data_metric(p.metrics, 1, MetricType.DOUBLE, 2, None)
    assert m.is_null and m.WhichOneof("value") is None and pl.get_value(m, MetricType.DOUBLE) is None
    s = pl.append_data_metric(p.metrics, 2, MetricType.STRING, 2, {"a": [1, 2]})
    assert s.string_value == '{"a":[1,2]}'
    f = pl.append_data_metric(p.metrics, 3, MetricType.DOUBLE, 2, math.inf)
    assert f.double_value == math.inf


def test_ndeath_payload_has_only_bdseq_int64_and_no_seq() -> None:
    p = pl.decode(pl.bdseq_payload(255, 1234))
    assert not p.HasField("seq") and p.timestamp == 1234
    (m,) = p.metrics
    assert (m.name, m.datatype, m.WhichOneof("value"), m.long_value) == ("bdSeq", DataType.Int64, "long_value", 255)


@given(st.binary(max_size=64))
def test_decode_rejects_garbage_with_valueerror_only(data: bytes) -> None:
    try:
        pl.decode(data)
    except ValueError as exc:
        assert "not a Sparkplug B payload" in str(exc)


def test_seq_and_alias_zero_are_on_the_wire() -> None:
    p = Payload(seq=0)
    p.metrics.add(alias=0)
    back = pl.decode(p.SerializeToString())
    assert back.HasField("seq") and back.metrics[0].HasField("alias")
