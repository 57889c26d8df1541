"""What crosses from the collector to the publishers: plain values, no FOCAS types.

Kept apart from both sides so publish never depends on focas and collect never on MQTT.
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta


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


@dataclass(frozen=True, slots=True)
class Sample:
    """One metric value with the time the CNC reported it (epoch milliseconds, UTC)."""

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


# Each Sample field's slot setter, in field order: a Sample built without its frozen __init__ (new_sample,
# and edge.collect.changes inline, where a Python call per changed value is worth saving).
SAMPLE_SLOT_SETTERS = tuple(getattr(Sample, name).__set__
                            for name in ("name", "value", "type", "timestamp_ms", "quality", "historical"))


def _sample_builder() -> Callable[..., Sample]:
    """`new_sample(name, value, type, timestamp_ms, quality)`: the Sample that `Sample(...)` builds.

    A frozen dataclass's __init__ sets each field through object.__setattr__ (0.7 us a Sample); the
    poll tick builds one per changed value, so its change detector sets the slots directly (0.35 us).
    """
    new = object.__new__
    set_name, set_value, set_type, set_timestamp, set_quality, set_historical = SAMPLE_SLOT_SETTERS

    def new_sample(name: str, value: object, kind: MetricType, timestamp_ms: int, quality: Quality) -> Sample:
        sample = new(Sample)
        set_name(sample, name)
        set_value(sample, value)
        set_type(sample, kind)
        set_timestamp(sample, timestamp_ms)
        set_quality(sample, quality)
        set_historical(sample, False)
        return sample

    return new_sample


new_sample = _sample_builder()


_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


@functools.lru_cache(maxsize=4096)
def utc_datetime(epoch_ms: int) -> datetime:
    """The aware datetime of an epoch-ms time (a Sample's timestamp), exact (no float), cached: the samples
    of one poll share their timestamp, so a batch converts it once."""
    return _EPOCH + timedelta(milliseconds=epoch_ms)
