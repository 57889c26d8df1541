"""Typed values the protocol layer returns, whatever the transport (native FOCAS or packed surface).

Plain frozen dataclasses: the collector turns them into samples; nothing here knows bytes.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from datetime import datetime


class PmcType(enum.IntEnum):
    """pmc_rdpmcrng data_type: element width of a PMC range."""

    BYTE = 0
    WORD = 1
    LONG = 2
    FLOAT = 4  # 30i-B / 0i-F / PMi-A only
    DOUBLE = 5

    @property
    def width(self) -> int:
        return {0: 1, 1: 2, 2: 4, 4: 4, 5: 8}[int(self)]

    @property
    def struct_code(self) -> str:
        """The element's `struct` format: bytes unsigned (bit work stays 0..255), words and longs signed
        like FOCAS idata/ldata."""
        return {0: "B", 1: "h", 2: "i", 4: "f", 5: "d"}[int(self)]


class ParamType(enum.IntEnum):
    """Parameter record type codes as 0x0e/0x8d answer them (the simulator's size of a number)."""

    BIT = 0
    BYTE = 1
    WORD = 2
    TWO_WORD = 3
    REAL = 4


# Diagnosis records (0x30/0x93) carry other codes than parameters: 2 is a 2-word value on a 160i-W and a
# 31i answers a byte diagnosis with 0 (public captures); byte 0, word 1, 2-word 2, bit 3 is pyfanuc's
# readdiag table. A client therefore never sizes a diagnosis value by its type code.
DIAG_TYPE_CODES: dict[ParamType, int] = {
    ParamType.BYTE: 0, ParamType.WORD: 1, ParamType.TWO_WORD: 2, ParamType.BIT: 3, ParamType.REAL: 4,
}


PMC_AREAS = ("G", "F", "Y", "X", "A", "R", "T", "K", "C", "D", "M", "N", "E", "Z")


@dataclass(frozen=True, slots=True)
class SysInfo:
    """cnc_sysinfo (ODBSYS): identifies the series and sets the record stride (max_axis)."""

    addinfo: int
    max_axis: int
    cnc_type: str  # "16", "30", "31", " 0", ...
    mt_type: str  # " M", " T", ...
    series: str
    version: str
    axes: str  # ASCII digits, e.g. "04"

    @property
    def is_30i_style(self) -> bool:
        """30i/31i/32i (and 0i-F) answer the 8-byte 0x8d/0x93 forms; older ones the 4-byte 0x0e/0x30."""
        kind = self.cnc_type.strip()
        return kind in ("30", "31", "32") or (kind == "0" and self.max_axis > 8)

    @property
    def model_name(self) -> str:
        suffix = {1: "A", 2: "B", 3: "C", 4: "D", 6: "F"}.get((self.addinfo >> 8) & 0xFF, "")
        base = self.cnc_type.strip() + "i"
        return f"{base}-{suffix}{self.mt_type.strip()}" if suffix else f"{base}-{self.mt_type.strip()}"


@dataclass(frozen=True, slots=True)
class StatInfo:
    """cnc_statinfo wire payload: 7 shorts (aut, run, motion, mstb, emergency, alarm, edit)."""

    aut: int
    run: int
    motion: int
    mstb: int
    emergency: int
    alarm: int
    edit: int


@dataclass(frozen=True, slots=True)
class ParamRecord:
    """One parameter or diagnosis number: axis 0 = whole CNC, -1 = all axes, n = that axis."""

    number: int
    axis: int
    type: int
    values: tuple[int | float | None, ...]

    @property
    def value(self) -> int | float | None:
        """The single value (axis 0 or a requested axis) — slot 0."""
        return self.values[0] if self.values else None


@dataclass(frozen=True, slots=True)
class ActiveAlarm:
    number: int
    type: int
    axis: int
    message: str


@dataclass(frozen=True, slots=True)
class AlarmHistoryEntry:
    """One entry of the CNC alarm history ring; `occurred` is the CNC's own time (tz-aware, UTC)."""

    occurred: datetime
    axis_no: int
    alm_type: int
    alm_no: int
    message: str


@dataclass(frozen=True, slots=True)
class ProgramNumbers:
    running: int
    main: int


@dataclass(frozen=True, slots=True)
class ExecProgram:
    number: int
    name: str


@dataclass(frozen=True, slots=True)
class ProgramDirEntry:
    number: int
    size: int
    comment: str


@dataclass(frozen=True, slots=True)
class OperatorMessage:
    """cnc_rdopmsg: a message the machine shows its operator (number, kind, text)."""

    number: int
    type: int
    text: str


@dataclass(frozen=True, slots=True)
class TimerValue:
    """cnc_rdtimer: minutes plus milliseconds."""

    minutes: int
    msec: int


@dataclass(frozen=True, slots=True)
class ModalGCode:
    """cnc_rdgcode (ODBGCD): the G code active in one modal group of the active block, e.g. (0, "G01")."""

    group: int  # the group index the library answers
    code: str


@dataclass(frozen=True, slots=True)
class Capabilities:
    """Which operations a transport/control pair can do; the daemon asks instead of branching on transport."""

    transport: str
    supported: frozenset[str] = field(default_factory=frozenset)

    def can(self, operation: str) -> bool:
        return operation in self.supported
