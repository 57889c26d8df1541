"""Scaled values: a number as (int32 mantissa, decimals), as ODBM and REALPRM carry it.

Shared by the macro and parameter layouts, and by command validation (a write that cannot be represented
is refused before it reaches a CNC).
"""

from __future__ import annotations

import math
from decimal import Decimal

from edge.focas.errors import OutOfRange

# ---- scaled values (ODBM mcr_val/dec_val, REALPRM prm_val/dec_val) -------------------------------------
I32_MIN, I32_MAX = -(2**31), 2**31 - 1


def to_scaled(value: float, what: str = "value") -> tuple[int, int]:
    """(mantissa, decimals) with value == mantissa / 10**decimals, mantissa within int32.

    12.345 -> (12345, 3). A value with more significant digits than int32 holds is rounded to the most
    decimals that fit; one whose integer part does not fit raises OutOfRange.
    """
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise OutOfRange(5, what, message=f"expected a finite number, got {value!r}")
    exact = (Decimal(value) if isinstance(value, int) else Decimal(repr(value))).normalize()
    decimals = max(0, -int(exact.as_tuple().exponent))
    while True:
        mantissa = int(exact.scaleb(decimals).to_integral_value())
        if I32_MIN <= mantissa <= I32_MAX:
            return mantissa, decimals
        if decimals == 0:
            raise OutOfRange(5, what, message=f"{value!r} does not fit a 32-bit scaled integer")
        decimals -= 1


def from_scaled(mantissa: int, decimals: int) -> float:
    return mantissa / 10**decimals
