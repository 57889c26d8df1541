"""Sparkplug DATA payloads written straight to bytes, identical to what protobuf's serializer produces.

DATA messages are the hot path: every changed value of every machine goes through one. Building them
with the protobuf runtime costs about a microsecond per metric in object creation; here a metric is a
few byte concatenations from precomputed pieces (the alias field per metric, the timestamp field once per
distinct timestamp, the three Quality property blocks). tests/unit/publish/test_ddata.py checks the output against
`SerializeToString()` byte for byte.

Values the fast writers do not take exactly (an int for a Double metric, a float32 overflow, a bool for
an Int32, a string that is not UTF-8 encodable) go through the protobuf runtime instead, so their bytes,
and their errors, are the runtime's own.

Wire facts used (proto2, fields in number order): Payload timestamp=1, metrics=2, seq=3; Metric
alias=2, timestamp=3, is_historical=5, is_null=7, properties=9, int_value=10, long_value=11,
float_value=12, double_value=13, boolean_value=14, string_value=15.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from edge.publish import payload as pl
from edge.publish.sparkplug_b_pb2 import Payload
from edge.samples import MetricType, Quality

MASK32 = pl.MASK32
MASK64 = pl.MASK64

_SMALL_VARINTS = tuple(bytes((n,)) for n in range(128))
_PACK_FLOAT = struct.Struct("<f").pack
_PACK_DOUBLE = struct.Struct("<d").pack

# Field keys: (field number << 3) | wire type.
_PAYLOAD_TIMESTAMP = b"\x08"
_METRIC = b"\x12"
_PAYLOAD_SEQ = b"\x18"
_ALIAS = b"\x10"
_TIMESTAMP = b"\x18"
HISTORICAL = b"\x28\x01"
NULL = b"\x38\x01"
_INT_VALUE = b"\x50"
_LONG_VALUE = b"\x58"
_FLOAT_VALUE = b"\x65"
_DOUBLE_VALUE = b"\x69"
_TRUE = b"\x70\x01"
_FALSE = b"\x70\x00"
_STRING_VALUE = b"\x7a"


def varint(n: int) -> bytes:
    """Base-128 varint of an integer in 0..2**64-1; ValueError outside, as the runtime raises."""
    if 0 <= n < 0x80:
        return _SMALL_VARINTS[n]
    if n < 0 or n > MASK64:
        raise ValueError(f"{n} does not fit an unsigned 64-bit field")
    if n < 0x4000:
        return bytes(((n & 0x7F) | 0x80, n >> 7))
    if 1 << 35 <= n < 1 << 42:  # epoch milliseconds from 1971 to 2109: six bytes, no loop
        return bytes(((n & 0x7F) | 0x80, (n >> 7 & 0x7F) | 0x80, (n >> 14 & 0x7F) | 0x80,
                      (n >> 21 & 0x7F) | 0x80, (n >> 28 & 0x7F) | 0x80, n >> 35))
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


# The key and length byte of a metric record whose body is shorter than 128 bytes, by body length.
SHORT_RECORD_HEADERS = tuple(_METRIC + _SMALL_VARINTS[n] for n in range(128))


def alias_field(alias: int) -> bytes:
    return _ALIAS + varint(alias)


def timestamp_field(timestamp_ms: int) -> bytes:
    return _TIMESTAMP + varint(timestamp_ms)


def metric_record(body: bytes) -> bytes:
    """A metric body framed as one element of Payload.metrics."""
    return _METRIC + varint(len(body)) + body


_last_head: tuple[int, bytes] = (-1, b"")


def payload_head(timestamp_ms: int) -> bytes:
    """The payload's timestamp field; the messages of one loop turn mostly share the millisecond."""
    global _last_head
    if _last_head[0] != timestamp_ms:
        _last_head = (timestamp_ms, _PAYLOAD_TIMESTAMP + varint(timestamp_ms))
    return _last_head[1]


def payload_tail(seq: int) -> bytes:
    return _PAYLOAD_SEQ + varint(seq)


def _quality_field(quality: Quality) -> bytes:
    """The `properties` field holding only the Quality property, as the runtime writes it."""
    m = Payload.Metric()
    pl.add_quality(m, quality)
    return m.SerializeToString()


QUALITY_FIELD: dict[Quality, bytes] = {q: _quality_field(q) for q in Quality}


# ---- value fields: bytes, or None when the value needs the protobuf runtime ------------------------------
ValueField = Callable[[Any], "bytes | None"]


def _boolean(v: Any) -> bytes | None:
    if v is True:
        return _TRUE
    if v is False:
        return _FALSE
    return None


def _signed32(v: Any) -> bytes | None:
    return _INT_VALUE + varint(v & MASK32) if type(v) is int else None


def _signed64(v: Any) -> bytes | None:
    return _LONG_VALUE + varint(v & MASK64) if type(v) is int else None


def _unsigned32(v: Any) -> bytes | None:
    return _INT_VALUE + varint(v) if type(v) is int and 0 <= v <= MASK32 else None


def _unsigned64(v: Any) -> bytes | None:
    return _LONG_VALUE + varint(v) if type(v) is int and 0 <= v <= MASK64 else None


def _float32(v: Any) -> bytes | None:
    if type(v) is not float:
        return None
    try:
        return _FLOAT_VALUE + _PACK_FLOAT(v)
    except OverflowError:  # the runtime rounds to infinity instead
        return None


def _float64(v: Any) -> bytes | None:
    return _DOUBLE_VALUE + _PACK_DOUBLE(v) if type(v) is float else None


DOUBLE_FIELD = struct.Struct("<Bd").pack  # (0x69, value): the double_value field of a float, one C call


def _string(v: Any) -> bytes | None:
    try:
        data = (v if type(v) is str else pl.as_text(v)).encode()
    except (TypeError, ValueError, OverflowError):  # unencodable text or JSON: let the runtime raise its own error
        return None
    return _STRING_VALUE + varint(len(data)) + data


VALUE_FIELDS: dict[MetricType, ValueField] = {
    MetricType.BOOLEAN: _boolean,
    MetricType.INT8: _signed32,
    MetricType.INT16: _signed32,
    MetricType.INT32: _signed32,
    MetricType.INT64: _signed64,
    MetricType.UINT8: _unsigned32,
    MetricType.UINT16: _unsigned32,
    MetricType.UINT32: _unsigned64,
    MetricType.UINT64: _unsigned64,
    MetricType.FLOAT: _float32,
    MetricType.DOUBLE: _float64,
    MetricType.STRING: _string,
    MetricType.DATETIME: _unsigned64,
}


def runtime_value_field(mtype: MetricType, value: object) -> bytes:
    """The value field as the protobuf runtime encodes it; raises its TypeError/ValueError."""
    scratch = Payload()
    return pl.DATA_WRITERS[mtype](scratch.metrics, 0, 0, value).SerializeToString()[4:]
