"""DBIRTH payloads written straight to bytes, identical to what protobuf's serializer produces.

A reconnect at 1,000 machines sends 1,000 DBIRTHs of ~100 metrics: built with the protobuf runtime (a
`metrics.add`, the value, the engUnit and Quality properties and the description per metric) that was
~0.9 s of the event loop. Here a metric is the concatenation of pieces its layout and device keep (the
name and datatype fields, the metadata, the alias field) with the timestamp, the properties block (by unit
and quality, built once by the runtime) and the value field of edge.publish.ddata. A value the fast
writers do not take exactly goes through the runtime for that metric, and so do its errors.
tests/unit/publish/test_birth_bytes.py checks the output against the runtime byte for byte.

Wire facts used (proto2, fields in number order): Payload timestamp=1, metrics=2, seq=3; Metric name=1,
alias=2, timestamp=3, datatype=4, is_historical=5, is_null=7, metadata=8, properties=9, values 10-15.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from edge.publish import ddata as dd
from edge.publish import payload as pl
from edge.publish.device_table import DeviceTable, MetricLayout
from edge.publish.sparkplug_b_pb2 import Payload
from edge.samples import MetricSpec, MetricType, Quality

_NAME = b"\x0a"
_DATATYPE = b"\x20"

# What a layout's births need of each metric, by position: (name and datatype fields, metadata field,
# unit, type, value field writer); kept per layout object (layouts are shared and live while used).
_Static = tuple[bytes, bytes, bytes, str | None, MetricType, dd.ValueField]
_STATICS: dict[int, tuple[MetricLayout, list[_Static]]] = {}
_PROPERTIES: dict[tuple[str | None, int], bytes] = {}


def _metadata_field(spec: MetricSpec) -> bytes:
    if not spec.description:
        return b""
    m = Payload.Metric()
    m.metadata.description = spec.description
    return m.SerializeToString()


def _statics(layout: MetricLayout) -> list[_Static]:
    cached = _STATICS.get(id(layout))
    if cached is not None and cached[0] is layout:
        return cached[1]
    out: list[_Static] = []
    for spec in layout.specs.values():
        name = spec.name.encode()
        out.append((_NAME + dd.varint(len(name)) + name, _DATATYPE + dd.varint(pl.DATATYPE[spec.type]),
                    _metadata_field(spec), spec.unit, spec.type, dd.VALUE_FIELDS[spec.type]))
    if len(_STATICS) > 256:  # layouts come and go with reloads: keep the cache small
        _STATICS.clear()
    _STATICS[id(layout)] = (layout, out)
    return out


def _properties(unit: str | None, quality: int) -> bytes:
    """The properties field (engUnit if any, then Quality) as the runtime writes it."""
    key = (unit, quality)
    found = _PROPERTIES.get(key)
    if found is None:
        m = Payload.Metric()
        if unit:
            pl.add_property(m, pl.UNIT_PROPERTY, pl.DataType.String, unit)
        pl.add_quality(m, quality)
        found = _PROPERTIES[key] = m.SerializeToString()
    return found


def birth_metrics(dev: DeviceTable, ts: int, runtime: Callable[[int, int], bytes]) -> list[bytes]:
    """Each metric of `dev`'s birth as its Payload.metrics element (key, length, body), in layout order.

    `runtime(position, ts)` is the caller's runtime encoding of one metric (with its error handling), used
    for what the fast path does not take."""
    out: list[bytes] = []
    append = out.append
    ends = dev.alias_ends
    alias_data = dev.alias_data
    for p, ((name_field, datatype_field, metadata_field, unit, _mtype, write), sample) in enumerate(
            zip(_statics(dev.layout), dev.last, strict=True)):
        if sample is None:
            value, stamp, quality, historical = None, ts, Quality.GOOD, False
        else:
            value, stamp, quality, historical = sample.value, sample.timestamp_ms, sample.quality, sample.historical
        if value is None:
            field = dd.NULL
        else:
            written = write(value)
            if written is None:
                append(runtime(p, ts))
                continue
            field = written
        if not 0 <= stamp <= dd.MASK64:
            append(runtime(p, ts))
            continue
        if value is None:
            body = b"".join((name_field, alias_data[ends[p]:ends[p + 1]], dd.timestamp_field(stamp), datatype_field,
                             dd.HISTORICAL if historical else b"", field, metadata_field, _properties(unit, quality)))
        else:
            body = b"".join((name_field, alias_data[ends[p]:ends[p + 1]], dd.timestamp_field(stamp), datatype_field,
                             dd.HISTORICAL if historical else b"", metadata_field, _properties(unit, quality), field))
        append(dd.metric_record(body))
    return out


def birth_payload(ts: int, seq: int, metrics: Sequence[bytes]) -> bytes:
    """A Payload of these metric elements with its timestamp and seq."""
    return b"".join((b"\x08", dd.varint(ts), *metrics, dd.payload_tail(seq)))
