"""The simulated CNC's parameters and diagnosis numbers: which exist, their types, the stored values.

A realistic subset per profile with every parameter type represented; per-axis parameters keep one value
per controlled axis. Records follow cnc_rdparam's axis forms (0 or -1: every axis, n: that axis; a
non-axis parameter answers axis 0). Writes are checked against the type's range (EW_DATA) and the axis
form (EW_ATTRIB). Diagnosis values are not stored: MachineState computes them from the running cycle.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from edge.focas.errors import EW_ATTRIB, EW_DATA, EW_NUMBER, cnc_error
from edge.focas.model import ParamRecord, ParamType
from edge.focas.values import ALL_AXES
from edge.sim.profiles import Profile
from edge.sim.state_writes import WriteLog

PART_COUNT_PARAM = 6711
TOTAL_PARTS_PARAM = 6712
REQUIRED_PARTS_PARAM = 6713


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One parameter or diagnosis number: its type, whether it has a value per axis, its initial value(s)."""

    number: int
    type: ParamType
    per_axis: bool
    initial: tuple[int | float, ...]


def param_specs(profile: Profile) -> dict[int, ParamSpec]:
    """The parameters a machine of this profile has (a realistic subset, every type represented)."""
    n = profile.axis_count
    wide = profile.wide_records  # 30i-style controls keep lengths/speeds as real parameters

    def axes(*values: int | float) -> tuple[int | float, ...]:
        return tuple(values[i % len(values)] for i in range(n))

    length_type = ParamType.REAL if wide else ParamType.TWO_WORD
    stroke_plus = axes(500.0, 300.0, 0.0, 99999.0) if wide else axes(500000, 300000, 0, 99999999)
    stroke_minus = (axes(-10.0, -300.0, -450.0, -99999.0) if wide
                    else axes(-10000, -300000, -450000, -99999999))
    rapid = axes(24000.0, 24000.0, 18000.0, 3600.0) if wide else axes(24000, 24000, 18000, 3600)
    specs = [
        ParamSpec(0, ParamType.BIT, False, (0b0000_0011,)),  # setting: TVC/ISO
        ParamSpec(20, ParamType.BYTE, False, (4,)),  # I/O channel (4 = memory card)
        ParamSpec(1005, ParamType.BIT, True, axes(0b0000_0001)),
        ParamSpec(1020, ParamType.BYTE, True, tuple(ord(a[0]) for a in profile.axis_names)),  # axis name code
        ParamSpec(1022, ParamType.BYTE, True, axes(1, 2, 3, 0, 0)),
        ParamSpec(1320, length_type, True, stroke_plus),
        ParamSpec(1321, length_type, True, stroke_minus),
        ParamSpec(1420, length_type, True, rapid),  # rapid traverse rate
        ParamSpec(1815, ParamType.BIT, True, axes(0b0011_0000)),  # APZ (bit 4), APC (bit 5)
        ParamSpec(1825, ParamType.WORD, True, axes(3000)),  # servo loop gain
        ParamSpec(1850, ParamType.TWO_WORD, True, axes(120, -35, 0, 12)),  # grid shift
        ParamSpec(3281, ParamType.BYTE, False, (0,)),  # display language (0 English)
        ParamSpec(3401, ParamType.BIT, False, (0b0000_0001,)),  # DPI: decimal point programming
        ParamSpec(6711, ParamType.TWO_WORD, False, (0,)),  # parts count
        ParamSpec(6712, ParamType.TWO_WORD, False, (0,)),  # total parts
        ParamSpec(6713, ParamType.TWO_WORD, False, (500,)),  # parts required
        ParamSpec(8130, ParamType.BYTE, False, (n,)),  # number of controlled axes
    ]
    return {spec.number: spec for spec in specs}


def diag_specs(profile: Profile) -> dict[int, ParamSpec]:
    """Diagnosis numbers answered; values are computed from the running cycle when read."""
    n = profile.axis_count
    zero = tuple(0 for _ in range(n))
    specs = [
        ParamSpec(0, ParamType.BIT, False, (0,)),  # waiting states
        ParamSpec(300, ParamType.TWO_WORD, True, zero),  # position error (detection units)
        ParamSpec(308, ParamType.BYTE, True, zero),  # servo motor temperature (deg C)
        ParamSpec(309, ParamType.BYTE, True, zero),  # pulse coder temperature (deg C)
        ParamSpec(410, ParamType.WORD, False, (0,)),  # spindle load (%)
        ParamSpec(411, ParamType.WORD, False, (0,)),  # spindle speed meter (min-1)
        ParamSpec(980, ParamType.TWO_WORD, True, zero),  # machine position (detection units)
        ParamSpec(981, ParamType.TWO_WORD, True, zero),  # absolute position (detection units)
        ParamSpec(982, ParamType.TWO_WORD, True, zero),  # distance to go (detection units)
    ]
    return {spec.number: spec for spec in specs}


class Parameters:
    """One machine's parameter values and diagnosis specs; MachineState holds the lock around every call
    (see edge.sim.state)."""

    def __init__(self, profile: Profile, writes: WriteLog, start_parts: int) -> None:
        self.profile = profile
        self.specs = param_specs(profile)
        self.diag_specs = diag_specs(profile)
        self.values: dict[int, list[int | float]] = {
            number: list(spec.initial) for number, spec in self.specs.items()
        }
        self.values[PART_COUNT_PARAM] = [start_parts]
        self.values[TOTAL_PARTS_PARAM] = [1_000 + start_parts]
        self._writes = writes

    def spec(self, number: int) -> ParamSpec:
        spec = self.specs.get(number)
        if spec is None:
            raise cnc_error(EW_NUMBER, "cnc_rdparam", message=f"parameter {number} does not exist")
        return spec

    def count_parts(self, done: int) -> None:
        """`done` more parts finished: the parts count and the total parts count climb."""
        self.values[PART_COUNT_PARAM][0] = int(self.values[PART_COUNT_PARAM][0]) + done
        self.values[TOTAL_PARTS_PARAM][0] = int(self.values[TOTAL_PARTS_PARAM][0]) + done

    def _param_values(self, number: int) -> list[int | float]:
        return self.values[number]

    def param_records(self, first: int, last: int, axis: int) -> list[ParamRecord]:
        return self.records(first, last, axis, self.specs, self._param_values, "cnc_rdparam")

    def diag_records(self, first: int, last: int, axis: int,
                     values_of: Callable[[int], list[int | float]]) -> list[ParamRecord]:
        return self.records(first, last, axis, self.diag_specs, values_of, "cnc_diagnoss")

    def records(self, first: int, last: int, axis: int, specs: dict[int, ParamSpec],
                values_of: Callable[[int], list[int | float]], function: str) -> list[ParamRecord]:
        if not -1 <= axis <= self.profile.axis_count:
            raise cnc_error(EW_ATTRIB, function, message=(
                f"axis {axis} is outside -1..{self.profile.axis_count}"))
        numbers = [n for n in sorted(specs) if first <= n <= last]
        if not numbers:
            raise cnc_error(EW_NUMBER, function, message=f"no number exists in {first}..{last}")
        records = []
        for number in numbers:
            spec, values = specs[number], values_of(number)
            if not spec.per_axis:
                records.append(ParamRecord(number, 0, int(spec.type), (values[0],)))
            elif axis <= 0:
                records.append(ParamRecord(number, -1, int(spec.type), tuple(values)))
            else:
                records.append(ParamRecord(number, axis, int(spec.type), (values[axis - 1],)))
        return records

    def set(self, number: int, axis: int, value: int | float, protocol: str) -> None:
        spec = self.specs.get(number)
        if spec is None:
            raise cnc_error(EW_NUMBER, "cnc_wrparam", message=f"parameter {number} does not exist")
        stored = _checked_value(spec, value)
        values = self.values[number]
        if spec.per_axis:
            if axis == ALL_AXES:
                slots = list(range(len(values)))
            elif 1 <= axis <= len(values):
                slots = [axis - 1]
            else:
                raise cnc_error(EW_ATTRIB, "cnc_wrparam", message=(
                    f"parameter {number} is per axis: axis must be 1..{len(values)} or -1, got {axis}"))
        elif axis in (0, -1):
            slots = [0]
        else:
            raise cnc_error(EW_ATTRIB, "cnc_wrparam",
                            message=f"parameter {number} is not per axis: axis must be 0, got {axis}")
        old = values[slots[0]]
        for slot in slots:
            values[slot] = stored
        self._writes.add(protocol, f"param:{number}/{axis}" if spec.per_axis else f"param:{number}", old, stored)

    def value(self, number: int, axis: int) -> int | float:
        spec = self.spec(number)
        return self.values[number][axis - 1 if spec.per_axis else 0]


def _checked_value(spec: ParamSpec, value: int | float) -> int | float:
    """The value as the parameter type stores it; EW_DATA when it does not fit."""
    if spec.type == ParamType.REAL:
        if not math.isfinite(float(value)):
            raise cnc_error(EW_DATA, "cnc_wrparam", message=f"parameter {spec.number}: {value} is not finite")
        return float(value)
    if float(value) != int(value):
        raise cnc_error(EW_DATA, "cnc_wrparam",
                        message=f"parameter {spec.number} is {spec.type.name}: {value} is not an integer")
    limits = {ParamType.BIT: (0, 255), ParamType.BYTE: (-128, 255), ParamType.WORD: (-32768, 32767),
              ParamType.TWO_WORD: (-(2**31), 2**31 - 1)}[spec.type]
    if not limits[0] <= int(value) <= limits[1]:
        raise cnc_error(EW_DATA, "cnc_wrparam", message=(
            f"parameter {spec.number} is {spec.type.name}: {value} is outside {limits[0]}..{limits[1]}"))
    return int(value)
