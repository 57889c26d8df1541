"""The simulated machine's write log: every accepted write, in order, for tests and the admin endpoint.

Each area that takes writes (macros, PMC, parameters, the clock) appends here; nothing else does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple


class WriteRecord(NamedTuple):
    """One accepted write: gateway time (epoch s), protocol (native/packed/admin), target, old, new."""

    time: float
    protocol: str
    target: str
    old: object
    new: object


class WriteLog:
    """The accepted writes of one machine (path), stamped with the machine's injected clock."""

    def __init__(self, time_source: Callable[[], float]) -> None:
        self._time = time_source
        self.records: list[WriteRecord] = []

    def add(self, protocol: str, target: str, old: object, new: object) -> None:
        self.records.append(WriteRecord(self._time(), protocol, target, old, new))

    def matching(self, target_prefix: str) -> list[WriteRecord]:
        return [w for w in self.records if w.target.startswith(target_prefix)]
