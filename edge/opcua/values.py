"""A Sample as an OPC UA DataValue: the metric's type, the CNC's timestamp, a status from its quality.

SourceTimestamp is the CNC time the sample carries; ServerTimestamp is the gateway's clock when the
server took the value. A value whose status is Bad carries no value (OPC 10000-4 §7.7.1: a client must
ignore it, so the server sets it null).
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime

from asyncua import ua

from edge.opcua.layout import OFFLINE_STATUS, VARIANT_TYPES, status_name
from edge.samples import MetricType, Sample

_VARIANT: dict[MetricType, ua.VariantType] = {kind: getattr(ua.VariantType, name)
                                              for kind, name in VARIANT_TYPES.items()}
_STATUS: dict[str, ua.StatusCode] = {}
_NULL = ua.Variant(None, ua.VariantType.Null)
_INTEGERS = frozenset({MetricType.INT8, MetricType.INT16, MetricType.INT32, MetricType.INT64, MetricType.UINT8,
                       MetricType.UINT16, MetricType.UINT32, MetricType.UINT64})
_FLOATS = frozenset({MetricType.FLOAT, MetricType.DOUBLE})


class SharedDataValue(ua.DataValue):
    """A DataValue the gateway never changes after building it, so it is shared rather than copied.

    asyncua deep-copies the DataValue for every monitored item a change reaches (MonitoredItemValues keeps
    a private copy in case the caller mutates it): with a client subscribed to every value that copy was
    most of the server's CPU. Nothing in the server or here mutates a stored DataValue.
    """

    __slots__ = ()

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


def utc(epoch_ms: int) -> datetime:
    return datetime.fromtimestamp(epoch_ms / 1000, UTC)


def data_value(sample: Sample, server_time: datetime) -> ua.DataValue:
    """The DataValue a node shows for `sample` (value of the node's type, or null with a Bad status)."""
    status = status_code(status_name(sample.quality))
    variant = _NULL
    if not status.is_bad() and sample.value is not None:
        value = _convert(sample.value, sample.type)
        if value is not None:
            variant = _fast_variant(value, _VARIANT[sample.type])
        else:
            status = status_code("BadTypeMismatch")
    return SharedDataValue(variant, StatusCode=status, SourceTimestamp=utc(sample.timestamp_ms),
                        ServerTimestamp=server_time)


def offline_value(server_time: datetime) -> ua.DataValue:
    """What every value of a machine shows while its CNC session is down."""
    return SharedDataValue(_NULL, StatusCode=status_code(OFFLINE_STATUS), SourceTimestamp=server_time,
                        ServerTimestamp=server_time)


def _convert(value: object, kind: MetricType) -> object:
    """The Python value asyncua encodes as `kind`, or None when the sample's value does not fit it."""
    if kind in _FLOATS:
        return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
    if kind in _INTEGERS:
        return int(value) if isinstance(value, int) else None
    if kind is MetricType.BOOLEAN:
        return value if isinstance(value, bool) else None
    if kind is MetricType.STRING:
        return value if isinstance(value, str) else str(value)
    if kind is MetricType.DATETIME:
        return utc(value) if isinstance(value, int) and not isinstance(value, bool) else None
    return None


def client_value(variant: ua.Variant, kind: MetricType) -> tuple[bool, object]:
    """(fits, value) of a value a client wrote to a node of type `kind`: the variant type must be the node's
    (no silent conversion: a Float written to a Double node is a type mismatch, as OPC 10000-4 asks)."""
    if variant is None or variant.VariantType != _VARIANT[kind] or variant.is_array or variant.Value is None:
        return False, None
    return True, variant.Value
