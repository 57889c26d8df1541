"""A Sample as an OPC UA DataValue: the metric's type, the CNC's timestamp, a status from its quality.

SourceTimestamp is the CNC time the sample carries; ServerTimestamp is the gateway's clock when the
server took the value. A value whose status is Bad carries no value (OPC 10000-4 §7.7.1: a client must
ignore it, so the server sets it null).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any, NamedTuple

from asyncua import ua

from edge.opcua.encoding import ENCODERS, MAX_MS, MIN_MS, TICKS_PER_MS, WIN_EPOCH_OFFSET_MS, ticks
from edge.opcua.layout import OFFLINE_STATUS, VARIANT_TYPES, status_name
from edge.samples import MetricType, Quality, Sample, utc_datetime

_VARIANT: dict[MetricType, ua.VariantType] = {kind: getattr(ua.VariantType, name)
                                              for kind, name in VARIANT_TYPES.items()}
_STATUS: dict[str, ua.StatusCode] = {}
_NULL = ua.Variant(None, ua.VariantType.Null)
_INTEGERS = frozenset({MetricType.INT8, MetricType.INT16, MetricType.INT32, MetricType.INT64, MetricType.UINT8,
                       MetricType.UINT16, MetricType.UINT32, MetricType.UINT64})
_FLOATS = frozenset({MetricType.FLOAT, MetricType.DOUBLE})


_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


class SharedDataValue(ua.DataValue):
    """A DataValue the gateway never changes after building it, so it is shared rather than copied, and
    encoded once (`encoded`: its OPC UA binary form, edge.opcua.encoding) for every client it reaches.

    asyncua deep-copies the DataValue for every monitored item a change reaches (MonitoredItemValues keeps
    a private copy in case the caller mutates it): with a client subscribed to every value that copy was
    most of the server's CPU. Nothing in the server or here mutates a stored DataValue.
    """

    __slots__ = ("encoded",)

    def __deepcopy__(self, memo: object) -> SharedDataValue:
        return self

    def __copy__(self) -> SharedDataValue:
        return self




def variant_type(kind: MetricType) -> ua.VariantType:
    return _VARIANT[kind]


def status_code(name: str) -> ua.StatusCode:
    code = _STATUS.get(name)
    if code is None:
        code = _STATUS[name] = ua.StatusCode(getattr(ua.StatusCodes, name))
    return code


_WIN_EPOCH_US = 11_644_473_600_000_000  # OPC UA DateTime's epoch (1601-01-01) is this many us before Unix's
WIN_EPOCH_US = _WIN_EPOCH_US


class ServerTime(NamedTuple):
    """The gateway's clock for one batch of values: ServerTimestamp as asyncua holds it and as it encodes it."""

    when: datetime
    ticks: int


def server_time(epoch_ns: int) -> ServerTime:
    """ServerTime of a `time.time_ns()` reading, to the microsecond a datetime holds (so `ticks` is what
    asyncua encodes `when` as)."""
    us = epoch_ns // 1000
    return ServerTime(_EPOCH + timedelta(microseconds=us), (us + _WIN_EPOCH_US) * 10)


def server_now() -> ServerTime:
    return server_time(time.time_ns())


class LazyDataValue(SharedDataValue):
    """A sample's SharedDataValue whose Variant and timestamps are made on first access (`__getattr__`:
    Python calls it for a slot not set yet), from what it was encoded with.

    A monitored value is encoded (the notification's bytes) and kept as the item's last value, to compare
    the next one with (`same_reading`); its Variant and datetimes are only needed when a client reads the
    node or an item on asyncua's own path (a deadband) looks into it. Building them for every change took
    about 1 of the 2.5 us a value cost to build, and left two more objects for the collector to sweep.
    """

    __slots__ = ("raw", "server", "stamp", "vtype")

    def __getattr__(self, name: str) -> Any:
        if name not in _LAZY_FIELDS:
            raise AttributeError(name)
        _fill(self)
        return getattr(self, name)


def _fill(value: LazyDataValue) -> None:
    vtype = value.vtype  # (an AttributeError for a LazyDataValue not made by data_value: never filled)
    # the Variant asyncua's constructor makes (its checks pass: the value was encoded as `vtype`)
    value.Value = _NULL if vtype is _NULL_TYPE else ua.Variant(value.raw, vtype)
    value.SourceTimestamp = utc_datetime(value.stamp)
    value.ServerTimestamp = value.server.when
    value.Encoding = 0
    value.SourcePicoseconds = value.ServerPicoseconds = None


_LAZY_FIELDS = frozenset({"Value", "SourceTimestamp", "ServerTimestamp", "Encoding", "SourcePicoseconds",
                          "ServerPicoseconds"})
_NULL_TYPE = ua.VariantType.Null
_new = object.__new__


def _lazy(raw: object, vtype: ua.VariantType, status: ua.StatusCode, stamp: int, server: ServerTime,
          encoded: bytes) -> LazyDataValue:
    """A LazyDataValue, its slots stored directly (no dataclass __init__ and __post_init__: 0.2 us, not 0.8)."""
    made = _new(LazyDataValue)
    made.raw = raw
    made.vtype = vtype
    made.StatusCode = status
    made.stamp = stamp
    made.server = server
    made.encoded = encoded
    return made


def same_reading(previous: ua.DataValue, value: ua.DataValue) -> bool:
    """Whether a client would see no change from `previous` to `value` (asyncua's default trigger,
    StatusValue: the same status and Variant), without filling two LazyDataValues to tell."""
    if previous is value:
        return True
    if type(previous) is LazyDataValue and type(value) is LazyDataValue:
        return (previous.raw == value.raw and previous.vtype is value.vtype
                and (previous.StatusCode is value.StatusCode or previous.StatusCode == value.StatusCode))
    return bool(previous.StatusCode == value.StatusCode and previous.Value == value.Value)


def _shared(variant: ua.Variant, status: ua.StatusCode, source: datetime, server: datetime,
            encoded: bytes) -> SharedDataValue:
    made = SharedDataValue(variant, StatusCode=status, SourceTimestamp=source, ServerTimestamp=server)
    made.encoded = encoded
    return made


_NULL_ENCODER = ENCODERS[ua.VariantType.Null]


def _status_of(quality: object) -> tuple[ua.StatusCode, bool, int]:
    status = status_code(status_name(quality))
    return status, status.is_bad(), status.value


_QUALITY_STATUS = {quality: _status_of(quality) for quality in Quality}  # quality -> (status, is bad, its code)
QUALITY_STATUS = _QUALITY_STATUS


def data_value(sample: Sample, server: ServerTime) -> SharedDataValue:
    """The DataValue a node shows for `sample` (value of the node's type, or null with a Bad status).

    Called for every monitored value change: `ticks` and the conversion of a value already of the node's Python
    type are inlined."""
    status, bad, code = _QUALITY_STATUS.get(sample.quality) or _status_of(sample.quality)
    stamp = sample.timestamp_ms
    source = (stamp + WIN_EPOCH_OFFSET_MS) * TICKS_PER_MS if MIN_MS < stamp < MAX_MS else ticks(stamp)
    value = sample.value
    if not bad and value is not None:
        native, convert, vtype, encode = _KINDS[sample.type]
        if type(value) is not native:
            value = convert(value)
        if value is not None:
            try:
                encoded = encode(value, code, source, server.ticks)
            except (struct.error, OverflowError):  # outside the node's type (an Int16 of 40000)
                encoded = None
            if encoded is not None:
                return _lazy(value, vtype, status, stamp, server, encoded)
        status = status_code("BadTypeMismatch")
        code = status.value
    encoded = _NULL_ENCODER(None, code, source, server.ticks)
    return _lazy(None, _NULL_TYPE, status, stamp, server, encoded)


def offline_value(server: ServerTime) -> SharedDataValue:
    """What every value of a machine shows while its CNC session is down."""
    status = status_code(OFFLINE_STATUS)
    encoded = _NULL_ENCODER(None, status.value, server.ticks, server.ticks)
    return _shared(_NULL, status, server.when, server.when, encoded)


def _to_float(value: object) -> object:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _to_int(value: object) -> object:
    return int(value) if isinstance(value, int) else None


def _to_bool(value: object) -> object:
    return value if isinstance(value, bool) else None


def _to_str(value: object) -> object:
    return value if isinstance(value, str) else str(value)


def _to_datetime(value: object) -> object:
    return utc_datetime(value) if isinstance(value, int) and not isinstance(value, bool) else None


# metric type -> the Python value asyncua encodes as that type, or None when the sample's value does not fit it
_CONVERT: dict[MetricType, Callable[[object], object]] = {
    **dict.fromkeys(_FLOATS, _to_float), **dict.fromkeys(_INTEGERS, _to_int), MetricType.BOOLEAN: _to_bool,
    MetricType.STRING: _to_str, MetricType.DATETIME: _to_datetime}
# the Python type a metric type's values usually have, taken as it is (a subclass, bool for int, goes through
# the converter); None: always converted
_NATIVE: dict[MetricType, type | None] = {
    **dict.fromkeys(_FLOATS, float), **dict.fromkeys(_INTEGERS, int), MetricType.BOOLEAN: bool,
    MetricType.STRING: str, MetricType.DATETIME: None}
# metric type -> (native type, converter, variant type, encoder): one lookup per value
_KINDS = {kind: (_NATIVE[kind], convert, _VARIANT[kind], ENCODERS[_VARIANT[kind]])
          for kind, convert in _CONVERT.items()}
KINDS = _KINDS  # (edge.opcua.address_space encodes the usual value inline, data_value the others)
NULL_TYPE = _NULL_TYPE


def client_value(variant: ua.Variant, kind: MetricType) -> tuple[bool, object]:
    """(fits, value) of a value a client wrote to a node of type `kind`: the variant type must be the node's
    (no silent conversion: a Float written to a Double node is a type mismatch, as OPC 10000-4 asks)."""
    if variant is None or variant.VariantType != _VARIANT[kind] or variant.is_array or variant.Value is None:
        return False, None
    return True, variant.Value
