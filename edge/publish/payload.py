"""Sparkplug B metric encoding: which protobuf field carries which datatype, and how values round-trip.

The mapping follows Tahu Java, the TCK and Ignition rather than the loose wording of the spec
(shared/docs/sparkplug.md §1.10): Int8/Int16/Int32/UInt8/UInt16 travel in `int_value`, signed ones
sign-extended to 32 bits; Int64/UInt64/UInt32/DateTime travel in `long_value`, Int64 as two's complement.
Decoding accepts what hosts differ on (any integer type in either field, signed ones sign-extended to
the field) but never wraps: a number outside its datatype is a ValueError, as a DCMD value must land as sent.

The DATA path is table-driven: one precomputed writer per type appends a metric with a single protobuf call,
so encoding costs no per-metric branching in Python.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.samples import MetricType, Quality

Metric = Payload.Metric
MetricList = Any  # the repeated-field container of Payload.metrics (a upb type without a public name)

MASK32 = 0xFFFF_FFFF
MASK64 = 0xFFFF_FFFF_FFFF_FFFF

DATATYPE: dict[MetricType, int] = {
    MetricType.BOOLEAN: DataType.Boolean,
    MetricType.INT8: DataType.Int8,
    MetricType.INT16: DataType.Int16,
    MetricType.INT32: DataType.Int32,
    MetricType.INT64: DataType.Int64,
    MetricType.UINT8: DataType.UInt8,
    MetricType.UINT16: DataType.UInt16,
    MetricType.UINT32: DataType.UInt32,
    MetricType.UINT64: DataType.UInt64,
    MetricType.FLOAT: DataType.Float,
    MetricType.DOUBLE: DataType.Double,
    MetricType.STRING: DataType.String,
    MetricType.DATETIME: DataType.DateTime,
}
METRIC_TYPE: dict[int, MetricType] = {dt: mt for mt, dt in DATATYPE.items()}

BDSEQ_METRIC = "bdSeq"
REBIRTH_METRIC = "Node Control/Rebirth"
QUALITY_PROPERTY = "Quality"
UNIT_PROPERTY = "engUnit"


def as_text(value: object) -> str:
    """Strings pass through; structured values (alarm lists, events) become compact JSON."""
    if isinstance(value, str):
        return value
    return json.dumps(value, separators=(",", ":"), default=str)


# A writer appends one metric carrying `value` and returns it so the caller can add flags or properties.
DataWriter = Callable[[MetricList, int, int, Any], Metric]

DATA_WRITERS: dict[MetricType, DataWriter] = {
    MetricType.BOOLEAN: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, boolean_value=v),
    MetricType.INT8: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, int_value=v & MASK32),
    MetricType.INT16: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, int_value=v & MASK32),
    MetricType.INT32: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, int_value=v & MASK32),
    MetricType.INT64: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, long_value=v & MASK64),
    MetricType.UINT8: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, int_value=v),
    MetricType.UINT16: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, int_value=v),
    MetricType.UINT32: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, long_value=v),
    MetricType.UINT64: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, long_value=v),
    MetricType.FLOAT: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, float_value=v),
    MetricType.DOUBLE: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, double_value=v),
    MetricType.STRING: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, string_value=as_text(v)),
    MetricType.DATETIME: lambda ms, a, ts, v: ms.add(alias=a, timestamp=ts, long_value=v),
}

# The same mapping for a metric that already exists (births, commands, tests).
VALUE_SETTERS: dict[MetricType, Callable[[Metric, Any], None]] = {
    MetricType.BOOLEAN: lambda m, v: setattr(m, "boolean_value", bool(v)),
    MetricType.INT8: lambda m, v: setattr(m, "int_value", int(v) & MASK32),
    MetricType.INT16: lambda m, v: setattr(m, "int_value", int(v) & MASK32),
    MetricType.INT32: lambda m, v: setattr(m, "int_value", int(v) & MASK32),
    MetricType.INT64: lambda m, v: setattr(m, "long_value", int(v) & MASK64),
    MetricType.UINT8: lambda m, v: setattr(m, "int_value", int(v)),
    MetricType.UINT16: lambda m, v: setattr(m, "int_value", int(v)),
    MetricType.UINT32: lambda m, v: setattr(m, "long_value", int(v)),
    MetricType.UINT64: lambda m, v: setattr(m, "long_value", int(v)),
    MetricType.FLOAT: lambda m, v: setattr(m, "float_value", float(v)),
    MetricType.DOUBLE: lambda m, v: setattr(m, "double_value", float(v)),
    MetricType.STRING: lambda m, v: setattr(m, "string_value", as_text(v)),
    MetricType.DATETIME: lambda m, v: setattr(m, "long_value", int(v)),
}

_SIGNED_BITS = {MetricType.INT8: 8, MetricType.INT16: 16, MetricType.INT32: 32, MetricType.INT64: 64}
_UNSIGNED_BITS = {MetricType.UINT8: 8, MetricType.UINT16: 16, MetricType.UINT32: 32, MetricType.UINT64: 64}


def set_value(metric: Metric, mtype: MetricType, value: object) -> None:
    """Store `value` in the field Tahu uses for `mtype`; None becomes an explicit null (no value field)."""
    if value is None:
        metric.is_null = True
        return
    VALUE_SETTERS[mtype](metric, value)


def append_data_metric(metrics: MetricList, alias: int, mtype: MetricType, timestamp_ms: int,
                       value: object) -> Metric:
    """Append a DATA metric: alias, timestamp, value; no name and no datatype (spec §1.6)."""
    if value is None:
        return metrics.add(alias=alias, timestamp=timestamp_ms, is_null=True)
    return DATA_WRITERS[mtype](metrics, alias, timestamp_ms, value)


def _signed(raw: int, bits: int) -> int:
    raw &= (1 << bits) - 1
    return raw - (1 << bits) if raw >> (bits - 1) else raw


def _integer_field(metric: Metric) -> int | None:
    which = metric.WhichOneof("value")
    if which == "int_value":
        return metric.int_value
    if which == "long_value":
        return metric.long_value
    return None


def _field_signed(metric: Metric) -> int | None:
    """The integer field read as two's complement of its own width (int_value 32 bits, long_value 64)."""
    which = metric.WhichOneof("value")
    if which == "int_value":
        return _signed(metric.int_value, 32)
    if which == "long_value":
        return _signed(metric.long_value, 64)
    return None


def _checked_signed(metric: Metric, mtype: MetricType) -> int:
    """A signed integer as sent (sign-extended to its field, as Tahu does), refused when out of range.

    A value that does not fit is never wrapped: 70000 for an Int16 would otherwise land as 4464. A form
    masked to the type's width (0xFFFF for -1) is refused too, as it cannot be told from 65535.
    """
    value = _field_signed(metric)
    if value is None:
        raise ValueError(f"{mtype.value} metric: expected int_value or long_value, got {metric.WhichOneof('value')}")
    bits = _SIGNED_BITS[mtype]
    low, high = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    if not low <= value <= high:
        raise ValueError(f"{mtype.value} metric: {value} is outside {low}..{high} (a negative value is sent "
                         "sign-extended to its field)")
    return value


def _checked_unsigned(metric: Metric, mtype: MetricType) -> int:
    """An unsigned integer within its width; a negative number (or a wider one) is refused."""
    raw = _integer_field(metric)
    bits = _UNSIGNED_BITS[mtype]
    if raw is None or raw >> bits:
        which = metric.WhichOneof("value")
        shown = f"{which}={raw}" if raw is None or _field_signed(metric) == raw else f"{_field_signed(metric)}"
        raise ValueError(f"{mtype.value} metric: expected an unsigned {bits}-bit integer (0..{(1 << bits) - 1}), "
                         f"got {shown}")
    return raw


def get_value(metric: Metric, mtype: MetricType) -> object:
    """Read a metric's value as `mtype`, accepting the encodings hosts actually send.

    Raises ValueError when the metric carries no value compatible with `mtype`.
    """
    if metric.is_null:
        return None
    which = metric.WhichOneof("value")
    if mtype in _SIGNED_BITS:
        return _checked_signed(metric, mtype)
    if mtype in _UNSIGNED_BITS:
        return _checked_unsigned(metric, mtype)
    if mtype is MetricType.DATETIME:
        raw = _integer_field(metric)
        if raw is None:
            raise ValueError(f"DateTime metric: expected long_value, got {which}")
        return raw
    if mtype is MetricType.BOOLEAN:
        if which == "boolean_value":
            return metric.boolean_value
        raw = _integer_field(metric)
        if raw in (0, 1):
            return bool(raw)
        raise ValueError(f"Boolean metric: expected boolean_value, got {which}")
    if mtype in (MetricType.FLOAT, MetricType.DOUBLE):
        if which == "float_value":
            return metric.float_value
        if which == "double_value":
            return metric.double_value
        raw = _integer_field(metric)
        if raw is None:
            raise ValueError(f"{mtype.value} metric: expected float_value or double_value, got {which}")
        return float(raw)
    if which == "string_value":
        return metric.string_value
    raise ValueError(f"String metric: expected string_value, got {which}")


def add_property(metric: Metric, key: str, datatype: int, value: object) -> None:
    """Append a typed property (type is required in births)."""
    props = metric.properties
    props.keys.append(key)
    pv = props.values.add(type=datatype)
    if datatype == DataType.String:
        pv.string_value = str(value)
    elif datatype in (DataType.Int8, DataType.Int16, DataType.Int32):
        pv.int_value = int(value) & MASK32  # type: ignore[call-overload]
    else:
        raise ValueError(f"property {key}: datatype {datatype} is not supported here")


def add_quality(metric: Metric, quality: int) -> None:
    """The `Quality` property hosts read: Int32 0 (BAD), 192 (GOOD) or 500 (STALE)."""
    add_property(metric, QUALITY_PROPERTY, DataType.Int32, quality)


def quality_of(metric: Metric) -> Quality:
    """A metric's Quality property, GOOD when absent (what Ignition assumes)."""
    props = metric.properties
    for key, pv in zip(props.keys, props.values, strict=False):
        if key == QUALITY_PROPERTY:
            return Quality(_signed(pv.int_value, 32))
    return Quality.GOOD


def add_birth_metric(metrics: MetricList, name: str, alias: int | None, mtype: MetricType, value: object,
                     timestamp_ms: int, *, unit: str | None = None, quality: int | None = Quality.GOOD,
                     description: str | None = None) -> Metric:
    """Append a BIRTH metric: name, alias, datatype, timestamp, value (or is_null), engUnit, Quality."""
    m: Metric = metrics.add(name=name, datatype=DATATYPE[mtype], timestamp=timestamp_ms)
    if alias is not None:
        m.alias = alias
    set_value(m, mtype, value)
    if unit:
        add_property(m, UNIT_PROPERTY, DataType.String, unit)
    if quality is not None:
        add_quality(m, quality)
    if description:
        m.metadata.description = description
    return m


def bdseq_payload(bdseq: int, timestamp_ms: int) -> bytes:
    """The NDEATH payload (Will and explicit): only the bdSeq metric as Int64, and no seq."""
    p = Payload(timestamp=timestamp_ms)
    p.metrics.add(name=BDSEQ_METRIC, datatype=DataType.Int64, timestamp=timestamp_ms, long_value=bdseq)
    return p.SerializeToString()


def decode(data: bytes) -> Payload:
    """Parse a Sparkplug payload; raises ValueError with the size when it is not one."""
    p = Payload()
    try:
        p.ParseFromString(data)
    except Exception as exc:  # google.protobuf.message.DecodeError and upb variants
        raise ValueError(f"not a Sparkplug B payload ({len(data)} bytes): {exc}") from exc
    return p
