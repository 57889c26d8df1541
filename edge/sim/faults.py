"""Faults a simulated CNC can be told to show, per machine, at runtime.

A FaultPlan is plain data plus a lock: tests (or the admin endpoint) set fields, the server consumes
them. Counted faults take effect for the next N occurrences and then clear themselves (-1 = until
cleared), so "inject -> see the error -> reconnect -> works" needs no second call. What each fault
looks like to a client (see docs/simulator.md):

=================  =============================================  ===========================
fault              server behaviour                               client sees
=================  =============================================  ===========================
latency            sleeps that many seconds before each answer    FocasTimeout past timeout
refuse             resets (RST) the next N new connections        ConnectionLost
drop_after         aborts the connection instead of answering     ConnectionLost
                   the Nth data request from now (1 = next)
hang               sends half of the next N answers, then         FocasTimeout
                   nothing more on that connection (no FIN)
garbage            answers the next N requests with bytes that    ProtocolError
                   are no FOCAS frame
ew                 command code or function name -> EW code       that CncError subclass
                   answered for it instead of data; "name/arg1"
                   narrows it to one first argument (positions/7:
                   one position kind, as a real EDM answers),
                   "name/arg1/arg3" further to one third
                   (read_params/1850/0: the axis-0 read only)
max_sessions       connections beyond this many are reset         ConnectionLost
=================  =============================================  ===========================
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

FOREVER = -1
GARBAGE = b"\x47\x41\x52\x42\x41\x47\x45\x21" * 3  # "GARBAGE!" x3: fails the sync check at byte 0


@dataclass
class FaultPlan:
    """The faults one machine shows now; every field may be changed while the server runs."""

    latency: float = 0.0
    refuse: int = 0
    drop_after: int | None = None
    hang: int = 0
    garbage: int = 0
    ew: dict[str | int, int] = field(default_factory=dict)
    hang_on: dict[str | int, int] = field(default_factory=dict)  # function name/command -> count (-1 always)
    max_sessions: int | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def clear(self) -> None:
        """No faults at all."""
        with self._lock:
            self.latency = 0.0
            self.refuse = self.hang = self.garbage = 0
            self.drop_after = None
            self.ew = {}
            self.hang_on = {}
            self.max_sessions = None

    def update(self, changes: dict[str, Any]) -> None:
        """Set fields from a mapping (admin endpoint, scenario file); ValueError names an unknown one."""
        known = {"latency", "refuse", "drop_after", "hang", "garbage", "ew", "hang_on", "max_sessions"}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(f"unknown fault(s) {unknown}; expected some of {sorted(known)}")
        with self._lock:
            for name, value in changes.items():
                if name == "ew":
                    self.ew = {_ew_key(k): int(v) for k, v in dict(value or {}).items()}
                elif name == "hang_on":
                    self.hang_on = {_ew_key(k): int(v) for k, v in dict(value or {}).items()}
                elif name == "latency":
                    self.latency = float(value)
                elif name in ("drop_after", "max_sessions"):
                    setattr(self, name, None if value is None else int(value))
                else:
                    setattr(self, name, int(value))

    def describe(self) -> dict[str, Any]:
        """The plan as JSON-friendly data."""
        with self._lock:
            return {"latency": self.latency, "refuse": self.refuse, "drop_after": self.drop_after,
                    "hang": self.hang, "garbage": self.garbage,
                    "ew": {str(k): v for k, v in self.ew.items()},
                    "hang_on": {str(k): v for k, v in self.hang_on.items()}, "max_sessions": self.max_sessions}

    # ---- consumed by the server ------------------------------------------------------------------
    def _take(self, name: str) -> bool:
        with self._lock:
            remaining = int(getattr(self, name))
            if remaining == 0:
                return False
            if remaining > 0:
                setattr(self, name, remaining - 1)
            return True

    def take_refuse(self) -> bool:
        """Whether to refuse the connection now arriving."""
        return self._take("refuse")

    def take_hang(self) -> bool:
        return self._take("hang")

    def take_hang_on(self, calls: list[tuple[int, str]]) -> bool:
        """Whether a request carrying one of these (command, function name) calls is to be applied and
        then its answer lost (half sent, then silence): aims a hang at one function, e.g. a write."""
        with self._lock:
            for command, name in calls:
                key = command if command in self.hang_on else name
                remaining = self.hang_on.get(key, 0)
                if remaining == 0:
                    continue
                if remaining > 0:
                    self.hang_on[key] = remaining - 1
                return True
            return False

    def take_garbage(self) -> bool:
        return self._take("garbage")

    def take_drop(self) -> bool:
        """Count one data request against drop_after; True when this is the one to drop on."""
        with self._lock:
            if self.drop_after is None:
                return False
            self.drop_after -= 1
            if self.drop_after > 0:
                return False
            self.drop_after = None
            return True

    def ew_for(self, command: int, name: str, args: tuple[int, ...] = (0, 0, 0)) -> int | None:
        """The EW code forced for this command (by code, table name, name/arg1 or name/arg1/arg3), if any."""
        with self._lock:
            for key in (command, name, f"{name}/{args[0]}", f"{name}/{args[0]}/{args[2]}"):
                code = self.ew.get(key)
                if code is not None:
                    return code
            return None


def _ew_key(key: str | int) -> str | int:
    """Command keys may be given as ints, "0x15"/"21" strings, or function names ("read_macros")."""
    if isinstance(key, int):
        return key
    text = key.strip()
    try:
        return int(text, 0)
    except ValueError:
        return text
