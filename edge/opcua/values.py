"""A Sample as an OPC UA DataValue: the metric's type, the CNC's timestamp, a status from its quality.

SourceTimestamp is the CNC time the sample carries; ServerTimestamp is the gateway's clock when the
server took the value. A value whose status is Bad carries no value (OPC 10000-4 §7.7.1: a client must
ignore it, so the server sets it null).
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import NamedTuple

from asyncua import ua

from edge.opcua.encoding import ENCODERS, ticks
from edge.opcua.layout import OFFLINE_STATUS, VARIANT_TYPES, status_name
from edge.samples import MetricType, Quality, Sample

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


def _variant_builder() -> Callable[[object, ua.VariantType], ua.Variant]:
    """`variant(value, vtype)`: the scalar Variant `ua.Variant(value, vtype)` builds, without its
    __post_init__ (type guessing and checks: 3.4 us against 0.9 us a value, and the value was already
    converted to `vtype` by `_convert`). Every changed value of every machine passes here."""
    new, set_field = object.__new__, object.__setattr__

    def variant(value: object, vtype: ua.VariantType) -> ua.Variant:
        made = new(ua.Variant)
        set_field(made, "Value", value)
        set_field(made, "VariantType", vtype)
        set_field(made, "Dimensions", None)
        set_field(made, "is_array", False)
        return made

    return variant


_fast_variant = _variant_builder()


def variant_type(kind: MetricType) -> ua.VariantType:
    return _VARIANT[kind]


def status_code(name: str) -> ua.StatusCode:
    code = _STATUS.get(name)
    if code is None:
        code = _STATUS[name] = ua.StatusCode(getattr(ua.StatusCodes, name))
    return code


@functools.lru_cache(maxsize=4096)
def utc(epoch_ms: int) -> datetime:
    """The aware datetime of an epoch-ms time, exact (no float), cached: the samples of one poll share
    their timestamp, so a batch converts it once."""
    return _EPOCH + timedelta(milliseconds=epoch_ms)


class ServerTime(NamedTuple):
    """The gateway's clock for one batch of values: ServerTimestamp as asyncua holds it and as it encodes it."""

    when: datetime
    ticks: int


def server_now() -> ServerTime:
    now = datetime.now(UTC)
    return ServerTime(now, ua.datetime_to_win_epoch(now))


def _shared(variant: ua.Variant, status: ua.StatusCode, source: datetime, server: datetime,
            encoded: bytes) -> SharedDataValue:
    made = SharedDataValue(variant, StatusCode=status, SourceTimestamp=source, ServerTimestamp=server)
    made.encoded = encoded
    return made


_NULL_ENCODER = ENCODERS[ua.VariantType.Null]


def _status_of(quality: object) -> tuple[ua.StatusCode, bool]:
    status = status_code(status_name(quality))
    return status, status.is_bad()


_QUALITY_STATUS = {quality: _status_of(quality) for quality in Quality}  # quality -> (status, is bad)


def data_value(sample: Sample, server: ServerTime) -> SharedDataValue:
    """The DataValue a node shows for `sample` (value of the node's type, or null with a Bad status)."""
    status, bad = _QUALITY_STATUS.get(sample.quality) or _status_of(sample.quality)
    stamp = sample.timestamp_ms
    if not bad and sample.value is not None:
        kind = sample.type
        value = _CONVERT[kind](sample.value)
        if value is not None:
            vtype = _VARIANT[kind]
            try:
                encoded = ENCODERS[vtype](value, status.value, ticks(stamp), server.ticks)
            except (struct.error, OverflowError):  # outside the node's type (an Int16 of 40000)
                encoded = None
            if encoded is not None:
                return _shared(_fast_variant(value, vtype), status, utc(stamp), server.when, encoded)
        status = status_code("BadTypeMismatch")
    encoded = _NULL_ENCODER(None, status.value, ticks(stamp), server.ticks)
    return _shared(_NULL, status, utc(stamp), server.when, encoded)


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
    return utc(value) if isinstance(value, int) and not isinstance(value, bool) else None


# metric type -> the Python value asyncua encodes as that type, or None when the sample's value does not fit it
_CONVERT: dict[MetricType, Callable[[object], object]] = {
    **dict.fromkeys(_FLOATS, _to_float), **dict.fromkeys(_INTEGERS, _to_int), MetricType.BOOLEAN: _to_bool,
    MetricType.STRING: _to_str, MetricType.DATETIME: _to_datetime}


def client_value(variant: ua.Variant, kind: MetricType) -> tuple[bool, object]:
    """(fits, value) of a value a client wrote to a node of type `kind`: the variant type must be the node's
    (no silent conversion: a Float written to a Double node is a type mismatch, as OPC 10000-4 asks)."""
    if variant is None or variant.VariantType != _VARIANT[kind] or variant.is_array or variant.Value is None:
        return False, None
    return True, variant.Value
