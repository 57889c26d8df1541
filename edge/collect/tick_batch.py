"""What one poll tick sends and how its answers are taken apart, prepared once per plan and combination of groups.

A tick is one request: the reads of every due group plus the CNC clock. What that request needs (its items,
each read's value extractor, where each read keeps its last result) depends only on the plan and the groups,
so the poller builds a TickBatch once per plan and combination of due groups and reuses it on every later
tick (edge.collect.poller `_batch_for`); the client then reuses the encoded request too, since the item
tuple is the same object.
"""

from __future__ import annotations

import enum
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from edge.collect import plan as pl
from edge.focas import items as it

SHARED_LIMIT = 4096  # distinct (reads, positions) kept to share; a fleet of a few models needs a few dozen


class ReadKind(enum.Enum):
    """What a tick does with a read's result beyond publishing its values."""

    VALUES = "values"
    ALARM_STATUS = "alarm_status"  # also decides whether the active alarms are read
    ALARM_HISTORY = "alarm_history"  # published as events, not values
    STATUS = "status"  # also feeds utilisation (edge.collect.plant_state) when the word changed


@dataclass(frozen=True, slots=True)
class TickBatch:
    """One combination of due groups, prepared once per plan: the reads, the request items (the clock
    last; a stable tuple, so the client reuses its encoded request), per read its kind and extractor, and
    where each read keeps its last result in the poller's per-plan list (`previous` fetches them all)."""

    reads: tuple[pl.PlannedRead, ...]
    items: tuple[it.ReadItem, ...]
    kinds: tuple[ReadKind, ...]
    extractors: tuple[pl.ValueExtractor, ...]
    positions: tuple[int, ...]  # per read, its index in the plan's reads
    # Per read, plan.element_coercion (None: not elementwise): unchanged elements of a moved list are skipped,
    # the moved ones coerced one by one.
    elementwise: tuple[tuple[type, Callable[[object], object]] | None, ...]
    previous: Callable[[list[object]], tuple[object, ...]]  # the per-plan list -> this batch's entries
    indices: range  # 0..len(reads)-1

    @classmethod
    def build(cls, reads: Sequence[pl.PlannedRead],
              extractor: Callable[[pl.PlannedRead], pl.ValueExtractor] = pl.value_extractor,
              positions: Sequence[int] | None = None) -> TickBatch:
        kinds = tuple(ReadKind.ALARM_STATUS if isinstance(r.item, it.ReadAlarmStatus)
                      else ReadKind.ALARM_HISTORY if isinstance(r.item, it.ReadAlarmHistory)
                      else ReadKind.STATUS if isinstance(r.item, it.ReadStatus)
                      else ReadKind.VALUES for r in reads)
        where = tuple(range(len(reads)) if positions is None else positions)
        if len(where) != len(reads):
            raise ValueError(f"{len(where)} positions for {len(reads)} reads")
        previous: Callable[[list[object]], tuple[object, ...]]
        if len(where) == 1:  # itemgetter of one index returns the item, not a 1-tuple
            (only,) = where
            previous = lambda last: (last[only],)  # noqa: E731
        elif where:
            previous = operator.itemgetter(*where)
        else:
            previous = lambda last: ()  # noqa: E731
        return cls(tuple(reads), (*(r.item for r in reads), it.ReadClock()), kinds,
                   tuple(extractor(r) for r in reads), where, tuple(pl.element_coercion(r) for r in reads), previous,
                   range(len(reads)))

    @classmethod
    def shared(cls, reads: Sequence[pl.PlannedRead], positions: Sequence[int]) -> TickBatch:
        """build, with the process's shared extractors, as one object for every poller asking the same reads at
        the same positions: machines polling alike share their plan's reads (MachinePlan.build), and a batch
        holds nothing of one machine (its last results stay in the poller); a copy each was ~5 kB a machine.
        The key's reads are held by the batch, so their ids stay theirs while the entry lives."""
        key = (*map(id, reads), -1, *positions)
        found = _SHARED.get(key)
        if found is None:
            found = cls.build(reads, pl.shared_value_extractor, positions)
            if len(_SHARED) >= SHARED_LIMIT:
                _SHARED.clear()
            _SHARED[key] = found
        return found


_SHARED: dict[tuple[int, ...], TickBatch] = {}
