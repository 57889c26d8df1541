"""Transport-neutral read requests: the vocabulary of `batch()`.

Each transport maps an item to its wire form (the native protocol to one or more subpackets of ONE
request PDU; the packed surface to its command ids). A batch returns one result per item, in order:
the decoded value, or the FocasError that item alone raised.
"""

from __future__ import annotations

from dataclasses import dataclass

from edge.focas.model import PmcType


@dataclass(frozen=True, slots=True)
class ReadItem:
    """Base of every read item; `operation` names it in capability tables and errors."""

    @property
    def operation(self) -> str:
        return type(self).__name__


@dataclass(frozen=True, slots=True)
class ReadSysInfo(ReadItem):
    """-> SysInfo"""


@dataclass(frozen=True, slots=True)
class ReadStatus(ReadItem):
    """-> StatInfo"""


@dataclass(frozen=True, slots=True)
class ReadAlarmStatus(ReadItem):
    """-> int (alarm bitfield; 0 = no alarm)"""


@dataclass(frozen=True, slots=True)
class ReadActiveAlarms(ReadItem):
    """-> list[ActiveAlarm]"""

    max_count: int = 10


@dataclass(frozen=True, slots=True)
class ReadProgramNumber(ReadItem):
    """-> ProgramNumbers"""


@dataclass(frozen=True, slots=True)
class ReadSequenceNumber(ReadItem):
    """-> int"""


@dataclass(frozen=True, slots=True)
class ReadExecProgramName(ReadItem):
    """-> ExecProgram"""


@dataclass(frozen=True, slots=True)
class ReadMainProgramPath(ReadItem):
    """-> str"""


@dataclass(frozen=True, slots=True)
class ReadProgramDirectory(ReadItem):
    """-> list[ProgramDirEntry]"""

    start: int = 1
    count: int = 19


@dataclass(frozen=True, slots=True)
class ReadFeed(ReadItem):
    """-> float | None (actual feed)"""


@dataclass(frozen=True, slots=True)
class ReadSpindleSpeed(ReadItem):
    """-> float | None (actual spindle speed)"""


@dataclass(frozen=True, slots=True)
class ReadSpindleLoad(ReadItem):
    """-> list[float | None] per spindle"""


POSITION_KINDS = ("absolute", "machine", "relative", "distance")


@dataclass(frozen=True, slots=True)
class ReadPositions(ReadItem):
    """-> list[float | None], one per controlled axis (kind: absolute, machine, relative, distance)"""

    kind: str = "absolute"


@dataclass(frozen=True, slots=True)
class ReadAxisNames(ReadItem):
    """-> list[str]"""


@dataclass(frozen=True, slots=True)
class ReadSpindleNames(ReadItem):
    """-> list[str]"""


@dataclass(frozen=True, slots=True)
class ReadServoMeter(ReadItem):
    """-> list[float | None] per axis (servo load meter)"""


@dataclass(frozen=True, slots=True)
class ReadControlledAxes(ReadItem):
    """-> int (what=2 controlled axes; what=1 spindles)"""

    what: int = 2


@dataclass(frozen=True, slots=True)
class ReadParams(ReadItem):
    """-> list[ParamRecord] for first..last (axis 0 whole CNC, -1 all, n one axis)"""

    first: int
    last: int
    axis: int = 0


@dataclass(frozen=True, slots=True)
class ReadDiag(ReadItem):
    """-> list[ParamRecord] for first..last"""

    first: int
    last: int
    axis: int = 0


@dataclass(frozen=True, slots=True)
class ReadMacros(ReadItem):
    """-> list[float | None] for #first..#last (None = vacant)"""

    first: int
    last: int


@dataclass(frozen=True, slots=True)
class ReadPmc(ReadItem):
    """-> list[int | float], one element per data_type-wide value, start..end in byte addresses"""

    area: str
    start: int
    end: int
    data_type: PmcType = PmcType.BYTE


@dataclass(frozen=True, slots=True)
class ReadClock(ReadItem):
    """-> datetime (naive: the CNC's local wall-clock time)"""


@dataclass(frozen=True, slots=True)
class ReadTimer(ReadItem):
    """-> TimerValue (kind 0 power-on, 1 operating, 2 cutting, 3 cycle, 4 free)"""

    kind: int = 0


TOOL_OFFSET_KINDS = ("length_geometry", "length_wear", "radius_geometry", "radius_wear")  # cnc_rdtofsr type 0..3


@dataclass(frozen=True, slots=True)
class ReadToolOffsets(ReadItem):
    """-> list[float | None], offsets first..first+count-1 of one kind (TOOL_OFFSET_KINDS index)"""

    kind: int = 0
    first: int = 1
    count: int = 1


@dataclass(frozen=True, slots=True)
class ReadWorkOffsets(ReadItem):
    """-> list[float | None] per controlled axis of one work offset (cnc_rdzofs number: 0 external,
    1..6 G54..G59). Vendor library only: the native protocol has no public wire form for it."""

    number: int = 1


@dataclass(frozen=True, slots=True)
class ReadModalGCodes(ReadItem):
    """-> list[ModalGCode] of the active block, every modal group (cnc_rdgcode type -1, block 1).
    Vendor library only: no public wire form."""


@dataclass(frozen=True, slots=True)
class ReadToolNumber(ReadItem):
    """-> int, the T code in use (cnc_modal type 108, active block). Vendor library only: no public wire form."""


WORK_OFFSET_FIRST_G = 54  # cnc_rdzofs offset number 1 is G54


def work_offset_number(g_code: int) -> int:
    """cnc_rdzofs's offset number for G54..G59; ValueError for any other G code."""
    if not WORK_OFFSET_FIRST_G <= g_code <= WORK_OFFSET_FIRST_G + 5:
        raise ValueError(f"work offset G{g_code}: expected 54..59")
    return g_code - WORK_OFFSET_FIRST_G + 1


@dataclass(frozen=True, slots=True)
class ReadOperatorMessages(ReadItem):
    """-> list[OperatorMessage] (the first message only on the native transport)"""


@dataclass(frozen=True, slots=True)
class ReadPathStatus(ReadItem):
    """-> StatInfo of one CNC path, whatever path the session reads (path discovery: a control answers a
    path it does not have with EW_PATH)"""

    path: int = 1


@dataclass(frozen=True, slots=True)
class ReadAlarmHistory(ReadItem):
    """-> list[AlarmHistoryEntry], newest first, at most `depth` (clamped to 1..250)"""

    depth: int = 100
