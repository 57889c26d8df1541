"""The simulated CNC's part program: the cycle it runs, and what a control says about the program.

The cycle: a part program runs (cut_seconds: MEM + STaRT + MoTioN, axes move, feed and spindle turn),
then the machine sits between parts (idle_seconds, reset after M30) and the cycle repeats. Everything
here is a function of the cycle time `t` (seconds since the machine started plus its phase), which
MachineState advances and passes in: the sequence number climbs through the program, one tool per
quarter of the cut, G01 while cutting, the operator message between parts, the run timers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from edge.focas.errors import EW_ATTRIB, EW_LENGTH, EW_NUMBER, cnc_error
from edge.focas.model import ExecProgram, ModalGCode, OperatorMessage, ProgramDirEntry, ProgramNumbers, TimerValue
from edge.sim.profiles import Profile

TOOL_OFFSET_COUNT = 64  # offsets the simulated control keeps per kind
WORK_OFFSET_COUNT = 6  # G54..G59 (number 0, the external offset, exists too)
LOAD_BLANK_MESSAGE = 2001  # the operator message shown between parts

# statinfo values (shared/docs/focas-protocol.md §3.4)
AUT_MDI, AUT_MEM, AUT_EDIT, AUT_JOG = 0, 1, 3, 5
RUN_RESET, RUN_STOP, RUN_HOLD, RUN_START = 0, 1, 2, 3
MOTION_NONE, MOTION_MOVING, MOTION_DWELL = 0, 1, 2

PROGRAMS: tuple[ProgramDirEntry, ...] = (
    ProgramDirEntry(1, 412, "(WARM UP)"),
    ProgramDirEntry(1234, 18_344, "(BRACKET OP10)"),
    ProgramDirEntry(1235, 9_120, "(BRACKET OP20)"),
    ProgramDirEntry(2000, 2_230, "(PROBE CYCLE)"),
    ProgramDirEntry(8000, 640, "(TOOL CHANGE SUB)"),
    ProgramDirEntry(9000, 1_024, "(MACRO LIB)"),
)


@dataclass(frozen=True, slots=True)
class CycleSpec:
    """Timing of the simulated part program; alarm_every = 0 means the cycle never raises alarms."""

    cut_seconds: float = 12.0
    idle_seconds: float = 4.0
    alarm_every: int = 0
    alarm_seconds: float = 3.0
    program_number: int = 1234

    @property
    def length(self) -> float:
        return self.cut_seconds + self.idle_seconds

    def phase_at(self, t: float) -> tuple[bool, float]:
        """(cutting?, seconds into that phase) at cycle time t."""
        within = t % self.length
        if within < self.cut_seconds:
            return True, within
        return False, within - self.cut_seconds

    def parts_between(self, start: float, end: float) -> int:
        """Parts finished (cuts ended) in the cycle-time interval (start, end]."""
        length, cut = self.length, self.cut_seconds
        return math.floor((end - cut) / length) - math.floor((start - cut) / length)


class Program:
    """The program side of one machine (path); reads only the cycle spec, the profile and `t`."""

    def __init__(self, profile: Profile, cycle: CycleSpec, path: int = 1) -> None:
        self.profile = profile
        self.cycle = cycle
        self.path = path  # the CNC path this program runs on: its memory folder is PATH<n>

    def program_numbers(self) -> ProgramNumbers:
        number = self.cycle.program_number
        return ProgramNumbers(running=number, main=number)

    def sequence_number(self, t: float) -> int:
        cutting, into = self.cycle.phase_at(t)
        return 10 + 10 * int(40 * into / self.cycle.cut_seconds) if cutting else 0

    def modal_g_codes(self, t: float) -> list[ModalGCode]:
        cutting, _ = self.cycle.phase_at(t)
        fixed = ((1, "G17"), (2, "G90"), (4, "G94"), (5, "G21"), (6, "G40"), (7, "G49"), (8, "G80"), (13, "G54"))
        return [ModalGCode(0, "G01" if cutting else "G00"), *(ModalGCode(g, code) for g, code in fixed)]

    def tool_number(self, t: float) -> int:
        cutting, into = self.cycle.phase_at(t)
        return 1 + min(3, int(4 * into / self.cycle.cut_seconds)) if cutting else 1

    def exec_program(self) -> ExecProgram:
        number = self.cycle.program_number
        return ExecProgram(number, f"O{number:04d}")

    def main_program_path(self) -> str:
        return f"//CNC_MEM/USER/PATH{self.path}/O{self.cycle.program_number:04d}"

    def operator_messages(self, t: float) -> list[OperatorMessage]:
        cutting, _ = self.cycle.phase_at(t)
        return [] if cutting else [OperatorMessage(LOAD_BLANK_MESSAGE, 0, "LOAD NEXT BLANK")]

    def tool_offsets(self, kind: int, first: int, last: int) -> list[float]:
        if not 0 <= kind <= 3:
            raise cnc_error(EW_ATTRIB, "cnc_rdtofsr", message=f"offset type {kind} is not 0..3")
        if not 1 <= first <= last <= TOOL_OFFSET_COUNT:
            raise cnc_error(EW_NUMBER, "cnc_rdtofsr",
                            message=f"offsets {first}..{last} are outside 1..{TOOL_OFFSET_COUNT}")
        bases = ((100.0, 2.5), (0.0, -0.002), (5.0, 0.5), (0.0, 0.001))
        base, step = bases[kind]
        return [round(base + step * n, 4) for n in range(first, last + 1)]

    def work_offsets(self, number: int) -> list[float]:
        if not 0 <= number <= WORK_OFFSET_COUNT:
            raise cnc_error(EW_NUMBER, "cnc_rdzofs",
                            message=f"work offset {number} is outside 0..{WORK_OFFSET_COUNT}")
        if number == 0:
            return [0.0] * self.profile.axis_count
        return [round(-100.0 * (index + 1) - 10.0 * number - 0.125, 3) for index in range(self.profile.axis_count)]

    @staticmethod
    def program_directory(start: int, count: int) -> list[ProgramDirEntry]:
        if count < 1:
            raise cnc_error(EW_LENGTH, "cnc_rdprogdir", message=f"count {count} is not positive")
        return [p for p in PROGRAMS if p.number >= start][:count]

    def timer(self, kind: int, t: float, on: float) -> TimerValue:
        """cnc_rdtimer at cycle time t, `on` seconds after the machine started."""
        length, cut = self.cycle.length, self.cycle.cut_seconds
        cycles, within = divmod(t, length)
        cutting = cycles * cut + min(within, cut)
        seconds = {0: 7_406_400 + on, 1: 3_110_000 + on, 2: 1_920_000 + cutting,
                   3: within if within < cut else 0.0, 4: 0.0}.get(kind)
        if seconds is None:
            raise cnc_error(EW_NUMBER, "cnc_rdtimer", message=f"timer type {kind} is not 0..4")
        minutes, rest = divmod(seconds, 60.0)
        return TimerValue(int(minutes), int(rest * 1000))
