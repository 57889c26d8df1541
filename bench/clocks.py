"""The fleet's CNC clocks: each simulated machine's own offset from this host's clock, and the bench's truth.

Real controls' clocks are set by hand: seconds to minutes off, at an arbitrary phase within the second. A
fleet whose clocks all equal the host's turns every CNC second at the same instant, so every machine's clock
narrowing (a read at the predicted flip) lands in the same few milliseconds; spread clocks remove that crowd.
The offsets are a function of the machine's index in the fleet (its device id m001, m002, ...), so the
simulators, the daemon's probes and the subscriber agree on them without passing them around.
"""

from __future__ import annotations

PHASE_STEP = 0.6180339887498949  # golden ratio: any run of consecutive machines spreads evenly over the second
WHOLE_SECONDS = 91  # and a whole-second part in -45..45 s: a hand-set clock, within max_skew_s (60 s default)


def cnc_clock_offset(index: int) -> float:
    """Seconds machine `index` (0-based) of a spread fleet runs ahead of this host's clock (negative: behind)."""
    whole = (index * 7919) % WHOLE_SECONDS - WHOLE_SECONDS // 2
    return whole + round((index * PHASE_STEP) % 1.0, 6)


def device_clock_offset(device_id: str) -> float:
    """The offset of the machine the bench config calls `device_id` (m001 is index 0; see machines_section)."""
    return cnc_clock_offset(int(device_id.lstrip("m")) - 1)
