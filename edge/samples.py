"""What crosses from the collector to the publishers: plain values, no FOCAS types.

Kept apart from both sides so publish never depends on focas and collect never on MQTT.
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any


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


SAMPLE_FIELDS = ("name", "value", "type", "timestamp_ms", "quality", "historical")


_new = object.__new__


class SampleDraft:
    """A Sample's slots, writable: the fast way to build a Sample without its frozen __init__.

    A frozen dataclass's __init__ sets each field through object.__setattr__ (0.7 us a Sample), its slot
    setters called one by one cost half that; the poll tick builds one per changed value, so it fills a
    draft (plain slot stores, the interpreter's fastest attribute writes) and then gives it Sample's class
    (`draft.__class__ = Sample`, which CPython allows between classes of the same slots): half the cost
    again. The assignment at import below fails if the two layouts ever part.
    """

    __slots__ = SAMPLE_FIELDS
    name: str
    value: object
    type: MetricType
    timestamp_ms: int
    quality: Quality
    historical: bool


def new_sample(name: str, value: object, kind: MetricType, timestamp_ms: int, quality: Quality,
               historical: bool = False) -> Sample:
    """The Sample that `Sample(name, value, kind, timestamp_ms, quality, historical)` builds, at a quarter of
    the cost: the one way the poll tick (edge.collect.changes) and the spool (edge.publish.spool_rows) build one."""
    sample: Any = _new(SampleDraft)
    sample.name = name
    sample.value = value
    sample.type = kind
    sample.timestamp_ms = timestamp_ms
    sample.quality = quality
    sample.historical = historical
    sample.__class__ = Sample
    return sample


if new_sample("", None, MetricType.BOOLEAN, 0, Quality.GOOD) != Sample("", None, MetricType.BOOLEAN, 0):
    raise AssertionError("new_sample does not build what Sample() builds")


_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


@functools.lru_cache(maxsize=4096)
def utc_datetime(epoch_ms: int) -> datetime:
    """The aware datetime of an epoch-ms time (a Sample's timestamp), exact (no float), cached: the samples
    of one poll share their timestamp, so a batch converts it once."""
    return _EPOCH + timedelta(milliseconds=epoch_ms)
