"""What crosses from the collector to the publishers: plain values, no FOCAS types.

Kept apart from both sides so publish never depends on focas and collect never on MQTT.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import NamedTuple


class MetricType(enum.Enum):
    """The value types a metric can have; publishers map them to Sparkplug datatypes and JSON."""

    BOOLEAN = "Boolean"
    INT8 = "Int8"
    INT16 = "Int16"
    INT32 = "Int32"
    INT64 = "Int64"
    UINT8 = "UInt8"
    UINT16 = "UInt16"
    UINT32 = "UInt32"
    UINT64 = "UInt64"
    FLOAT = "Float"
    DOUBLE = "Double"
    STRING = "String"
    DATETIME = "DateTime"  # epoch milliseconds, UTC

    # Members are singletons compared by identity: hash them by identity too, in C. Enum's own __hash__
    # is Python code (hash of the name), and every published value is looked up by its type.
    __hash__ = object.__hash__


class Quality(enum.IntEnum):
    """OPC-style quality codes as Sparkplug hosts (Ignition) read the `Quality` property."""

    GOOD = 192
    BAD = 0
    STALE = 500


class Sample(NamedTuple):
    """One metric value with the time the CNC reported it (epoch milliseconds, UTC).

    Immutable. A NamedTuple rather than a frozen dataclass: a poll tick builds one per changed value,
    and a frozen dataclass's __init__ (one object.__setattr__ per field) costs three times as much.
    Change a field with `sample._replace(...)`.
    """

    name: str
    value: object
    type: MetricType
    timestamp_ms: int
    quality: Quality = Quality.GOOD
    historical: bool = False


@dataclass(frozen=True, slots=True)
class MetricSpec:
    """A metric as declared in a birth: its name, type, engineering unit, and whether it can be written."""

    name: str
    type: MetricType
    unit: str | None = None
    writable: bool = False
    description: str | None = None
