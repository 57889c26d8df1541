"""Report by exception: which samples are worth publishing.

A numeric value is reported when it moves more than its absolute deadband away from the value last
REPORTED (not last seen), so a slow drift is still published once it adds up. Any change of quality
is a change. NaN equals NaN and None equals None here, so a vacant macro or an unreadable float does
not flood the broker; a change between a number and NaN/None is always reported. After `reset()`
(every (re)connect) the next value of every metric is reported, giving subscribers the full state.

The last reported samples are kept by position in a list, beside a name index shared by every detector
that names the same metrics (a fleet polling alike): a dict of ~90 samples was ~3.3 kB a machine, the list
~0.8 kB. Names outside the index (one the plan did not declare) go to a small dict of their own.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Iterable, Mapping, Sequence

from edge.samples import MetricType, Quality, Sample, new_sample

_PLAIN = frozenset({int, str, bool})  # types whose values differ exactly when they are unequal


class NameIndex(dict[str, int]):
    """Metric name -> position, shared by the detectors that declare the same names (a weakref target)."""

    __slots__ = ("__weakref__",)


_INDEXES: weakref.WeakValueDictionary[tuple[str, ...], NameIndex] = weakref.WeakValueDictionary()


def name_index(names: Sequence[str]) -> NameIndex:
    """The shared index of these names (one per distinct tuple while a detector uses it); a name given
    twice keeps its first position."""
    key = tuple(names)
    index = _INDEXES.get(key)
    if index is None:
        index = NameIndex()
        for name in key:
            index.setdefault(name, len(index))
        _INDEXES[key] = index
    return index


class ChangeDetector:
    """Per-machine memory of the last reported sample of each metric.

    `names`: the metrics the machine declares, so their samples are kept by position (any other name is
    kept too, in a dict of its own)."""

    __slots__ = ("_deadbands", "_extra", "_index", "_last")

    def __init__(self, deadbands: Mapping[str, float] | None = None, names: Sequence[str] = ()) -> None:
        self._deadbands: dict[str, float] = dict(deadbands or {})
        self._index = name_index(names)
        self._last: list[Sample | None] = [None] * len(self._index)
        self._extra: dict[str, Sample] = {}  # names outside the index

    def set_deadband(self, name: str, deadband: float) -> None:
        if deadband < 0 or math.isnan(deadband):
            raise ValueError(f"deadband of {name!r} must be >= 0, got {deadband}")
        self._deadbands[name] = deadband

    def reset(self) -> None:
        """Forget what was reported: the next sample of every metric is reported (full state)."""
        self._last[:] = [None] * len(self._last)
        self._extra.clear()

    def forget(self, name: str) -> None:
        position = self._index.get(name)
        if position is None:
            self._extra.pop(name, None)
        else:
            self._last[position] = None

    def _previous(self, name: str) -> Sample | None:
        position = self._index.get(name)
        return self._extra.get(name) if position is None else self._last[position]

    def _keep(self, sample: Sample) -> None:
        position = self._index.get(sample.name)
        if position is None:
            self._extra[sample.name] = sample
        else:
            self._last[position] = sample

    def filter(self, samples: Iterable[Sample]) -> list[Sample]:
        """The samples to publish, in order; they become the new reference values."""
        return [sample for sample in samples if self.offer(sample)]

    def offer(self, sample: Sample) -> bool:
        """True (and remember it) if `sample` differs enough from the last reported one."""
        if not self.would_report(sample.name, sample.value, sample.quality, sample.type):
            return False
        self._keep(sample)
        return True

    def report(self, name: str, value: object, kind: MetricType, timestamp_ms: int,
               quality: Quality = Quality.GOOD) -> Sample | None:
        """The sample to publish for this value (and remember it), or None when it is no change: the poll
        tick's single pass, building a Sample only for what changed (most values of a tick do not)."""
        position = self._index.get(name)
        previous = self._extra.get(name) if position is None else self._last[position]
        if previous is not None and previous.quality is quality and previous.type is kind:
            old = previous.value
            same_type = type(old) is type(value)
            if same_type and old == value:
                return None
            band = self._deadbands.get(name, 0.0)
            if same_type and not band:
                if type(value) is float:  # a moving position, feed or speed
                    if value != value and old != old:  # NaN stays NaN: no change
                        return None
                elif type(value) not in _PLAIN and not values_differ(old, value, band):
                    return None
                # an int, str or bool unequal to the last one of its type: values_differ would say so too
            elif not values_differ(old, value, band):
                return None
        sample = new_sample(name, value, kind, timestamp_ms, quality)
        if position is None:
            self._extra[name] = sample
        else:
            self._last[position] = sample
        return sample

    def would_report(self, name: str, value: object, quality: Quality, kind: MetricType) -> bool:
        """Whether a value would be reported, without remembering it (lets the poller build a Sample
        only for what changed: most values of a tick do not)."""
        previous = self._previous(name)
        if previous is None:
            return True
        if previous.quality != quality or previous.type != kind:
            return True
        old = previous.value
        if old == value and type(old) is type(value):  # the common case on a poll tick: nothing moved
            return False
        return values_differ(old, value, self._deadbands.get(name, 0.0))

    def last_reported(self) -> dict[str, Sample]:
        """The current picture as subscribers know it (for births after a rebirth request): the declared
        metrics in their order, then the others in the order they were first reported."""
        out = {name: sample for name, sample in zip(self._index, self._last, strict=True) if sample is not None}
        out.update(self._extra)
        return out


def values_differ(old: object, new: object, deadband: float = 0.0) -> bool:
    """Whether `new` is a reportable change from `old` under an absolute deadband."""
    if _is_number(old) and _is_number(new):
        a, b = float(old), float(new)  # type: ignore[arg-type]
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) != math.isnan(b)
        if deadband > 0:
            return abs(b - a) > deadband
        return old != new
    if type(old) is not type(new):
        return True
    return bool(old != new)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


__all__ = ["ChangeDetector", "Quality", "name_index", "values_differ"]
