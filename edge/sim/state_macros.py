"""The simulated CNC's custom macro variables: the common variables #100-#199 and #500-#999.

A variable holds a float or is vacant (None). Numbers outside the two ranges are EW_NUMBER, as on a
control without the optional larger variable sets; a written value must be finite (EW_DATA).
"""

from __future__ import annotations

import math

from edge.focas.errors import EW_DATA, EW_NUMBER, cnc_error
from edge.sim.state_writes import WriteLog

MACRO_RANGES = ((100, 199), (500, 999))  # common (volatile) and common (kept) variables


def _initial_macros() -> dict[int, float | None]:
    macros: dict[int, float | None] = {n: None for lo, hi in MACRO_RANGES for n in range(lo, hi + 1)}
    macros.update({100: 1.0, 101: 0.0, 110: 25.4, 500: 12.5, 501: 0.0, 502: 3.0, 503: -0.125,
                   510: 150.0, 511: 75.25, 999: 1.0})
    return macros


class Macros:
    """One machine's variables; MachineState holds the lock around every call (see edge.sim.state)."""

    def __init__(self, writes: WriteLog) -> None:
        self.values = _initial_macros()
        self._writes = writes

    @staticmethod
    def _check(number: int, function: str) -> None:
        for lo, hi in MACRO_RANGES:  # a loop, not any(): every macro read of every poll passes here
            if lo <= number <= hi:
                return
        ranges = ", ".join(f"#{lo}-#{hi}" for lo, hi in MACRO_RANGES)
        raise cnc_error(EW_NUMBER, function, message=f"macro #{number} is outside {ranges}")

    def read(self, first: int, last: int) -> list[float | None]:
        if last < first:
            raise cnc_error(EW_NUMBER, "cnc_rdmacror", message=f"range #{first}-#{last} is empty")
        self._check(first, "cnc_rdmacror")
        self._check(last, "cnc_rdmacror")
        macros = self.values
        try:
            return [macros[n] for n in range(first, last + 1)]
        except KeyError:
            gap = f"range #{first}-#{last} spans a gap"
        raise cnc_error(EW_NUMBER, "cnc_rdmacror", message=gap)

    def write(self, number: int, value: float | None, protocol: str) -> None:
        self._check(number, "cnc_wrmacro")
        if value is not None and not math.isfinite(value):
            raise cnc_error(EW_DATA, "cnc_wrmacro", message=f"value {value} is not a finite number")
        old = self.values[number]
        self.values[number] = None if value is None else float(value)
        self._writes.add(protocol, f"macro:{number}", old, self.values[number])
