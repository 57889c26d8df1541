"""The simulated CNC's motion: where the axes are, and what feed, spindle and servo meters show.

While cutting the axes follow a contour (linear axes a sine per axis, rotary axes turning with the
part); between parts they sit at home and the meters idle. Every value is a function of the cycle time
`t` that MachineState advances and passes in, of the machine's seed (so machines of a fleet differ) and,
for feed and spindle, of whether the machine is stopped (emergency stop).
"""

from __future__ import annotations

import math

from edge.focas.errors import EW_NUMBER, cnc_error
from edge.sim.profiles import Profile
from edge.sim.state_program import CycleSpec


class Motion:
    """The axes and spindles of one machine (path); reads only the profile, the cycle spec, the seed and `t`."""

    def __init__(self, profile: Profile, cycle: CycleSpec, seed: int) -> None:
        self.profile = profile
        self.cycle = cycle
        self.seed = seed

    def axis_positions(self, t: float) -> list[float]:
        """Absolute position of every axis at cycle time t: a contour while cutting, home between parts."""
        cutting, into = self.cycle.phase_at(t)
        if not cutting:
            return [0.0] * self.profile.axis_count
        p = into / self.cycle.cut_seconds
        return [self._contour(index, name, p) for index, name in enumerate(self.profile.axis_names)]

    def _contour(self, index: int, name: str, p: float) -> float:
        """Where axis `index` (called `name`) is at fraction p of the cut."""
        if name in "ABC":  # rotary: indexes / turns with the part
            return round((p * 360.0 * (3 if name == "C" else 1)) % 360.0, 3)
        amplitude = (120.0, 80.0, 25.0)[index % 3]
        wave = math.sin(2 * math.pi * (3 * p + 0.17 * index + 0.05 * self.seed))
        return round(amplitude * wave - (30.0 * p if index % 3 == 2 else 0.0), 3)

    def positions(self, kind: str, t: float) -> list[float]:
        now = self.axis_positions(t)
        if kind in ("absolute", "relative"):
            return now
        if kind == "machine":
            offsets = (-350.0, -200.0, -410.0, 0.0, 0.0)
            return [round(v + offsets[i % len(offsets)], 3) for i, v in enumerate(now)]
        if kind == "distance":
            ahead = self.axis_positions(t + 0.25)
            return [round(a - b, 3) for a, b in zip(ahead, now, strict=True)]
        raise cnc_error(EW_NUMBER, "cnc_position", message=f"unknown position kind {kind!r}")

    def _cut_wave(self, t: float, stopped: bool, speed: float) -> tuple[bool, float]:
        cutting, into = self.cycle.phase_at(t)
        return cutting and not stopped, math.sin(into * speed + self.seed)

    def actual_feed(self, t: float, stopped: bool) -> float:
        cutting, wave = self._cut_wave(t, stopped, 0.9)
        return float(round(1200 + 350 * wave)) if cutting else 0.0

    def spindle_speed(self, t: float, stopped: bool) -> float:
        cutting, wave = self._cut_wave(t, stopped, 0.4)
        return float(round(6000 + 150 * wave)) if cutting else 0.0

    def spindle_loads(self, t: float, stopped: bool) -> list[float]:
        cutting, wave = self._cut_wave(t, stopped, 1.3)
        main = round(38 + 22 * wave, 1) if cutting else 0.0
        return [main] + [round(main * 0.3, 1)] * (len(self.profile.spindle_names) - 1)

    def servo_meter(self, t: float, stopped: bool) -> list[float]:
        cutting, wave = self._cut_wave(t, stopped, 1.7)
        return [round((18 + 9 * wave + 4 * i) if cutting else 2.0 + i, 1)
                for i in range(self.profile.axis_count)]
