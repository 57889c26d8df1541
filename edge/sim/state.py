"""The simulated machine: one CNC's state, shared by every protocol server that serves it.

Pure model, no I/O. Time comes from an injected clock (`time_source`, seconds since the epoch), and the
machine catches up lazily: every public read first calls :meth:`MachineState.advance`, which replays the
cycle events (part finished, alarm raised, alarm cleared) between the last call and now. A test that
injects a fake clock gets exactly the same machine every run.

The cycle: a part program runs (MEM + STaRT + MoTioN, axes move, feed and spindle turn), then the machine
sits between parts (reset after M30) and the cycle repeats. Each finished part increments parameters
6711 (parts count) and 6712 (total parts). Machines with ``CycleSpec.alarm_every`` > 0 raise an alarm
between parts every that many cycles and clear it a few seconds later; every alarm enters the history
ring (250 entries, newest first) stamped with the CNC's local wall-clock time.

Methods are protocol-neutral: they take numbers and return the typed values of edge.focas.model, and
raise ``edge.focas.errors.cnc_error(code, function)`` for the conditions a real control answers with an
EW_* code (EW_NUMBER outside a range, EW_LENGTH for a PMC write over 32 bytes, EW_PASSWD for a parameter
write while the parameter-write-enable switch is off, ...). Every method is thread-safe (one RLock), so
an admin thread and the servers' event loop may share a machine.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime, tzinfo
from typing import NamedTuple
from zoneinfo import ZoneInfo

from edge.focas.errors import (
    EW_ATTRIB,
    EW_DATA,
    EW_LENGTH,
    EW_NUMBER,
    EW_PASSWD,
    cnc_error,
)
from edge.focas.model import (
    ActiveAlarm,
    AlarmHistoryEntry,
    ExecProgram,
    ModalGCode,
    OperatorMessage,
    ParamRecord,
    ParamType,
    PmcType,
    ProgramDirEntry,
    ProgramNumbers,
    StatInfo,
    SysInfo,
    TimerValue,
)
from edge.focas.values import ALL_AXES
from edge.sim.profiles import Profile, get_profile

TOOL_OFFSET_COUNT = 64  # offsets the simulated control keeps per kind
WORK_OFFSET_COUNT = 6  # G54..G59 (number 0, the external offset, exists too)
LOAD_BLANK_MESSAGE = 2001  # the operator message shown between parts

MACRO_RANGES = ((100, 199), (500, 999))  # common (volatile) and common (kept) variables
PMC_WRITE_MAX = 32  # bytes per pmc_wrpmcrng call; more is EW_LENGTH
ALARM_HISTORY_SIZE = 250
PART_COUNT_PARAM = 6711
TOTAL_PARTS_PARAM = 6712
REQUIRED_PARTS_PARAM = 6713

# statinfo values (shared/docs/focas-protocol.md §3.4)
AUT_MDI, AUT_MEM, AUT_EDIT, AUT_JOG = 0, 1, 3, 5
RUN_RESET, RUN_STOP, RUN_HOLD, RUN_START = 0, 1, 2, 3
MOTION_NONE, MOTION_MOVING, MOTION_DWELL = 0, 1, 2

# cnc_rdalmmsg alarm type numbers (30i): bit n of the alarm-status word is type n.
ALARM_TYPES = {"SW": 0, "PW": 1, "IO": 2, "PS": 3, "OT": 4, "OH": 5, "SV": 6, "SR": 7, "MC": 8,
               "SP": 9, "DS": 10, "IE": 11, "BG": 12, "SN": 13, "EX": 15}


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


class WriteRecord(NamedTuple):
    """One accepted write: gateway time (epoch s), protocol (native/packed/admin), target, old, new."""

    time: float
    protocol: str
    target: str
    old: object
    new: object


@dataclass(frozen=True, slots=True)
class AlarmEvent:
    """An alarm occurrence as the CNC records it: local wall-clock time plus the real instant."""

    local_time: datetime  # naive, CNC wall clock
    utc_time: datetime  # aware, the real instant (for tests)
    number: int
    type: int
    axis: int
    message: str

    def entry(self) -> AlarmHistoryEntry:
        """The history entry as the wire carries it: the CNC's wall-clock fields, labelled UTC.

        Both wire forms carry year..second with no zone; decoders take them as UTC (seed 000), so an
        encode/decode round trip of this entry is exact. The collector converts with the machine's zone.
        """
        return AlarmHistoryEntry(occurred=self.local_time.replace(tzinfo=UTC), axis_no=self.axis,
                                 alm_type=self.type, alm_no=self.number, message=self.message)


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One parameter or diagnosis number: its type, whether it has a value per axis, its initial value(s)."""

    number: int
    type: ParamType
    per_axis: bool
    initial: tuple[int | float, ...]


# Alarms the cycle raises between parts (number, type, axis, message), chosen in turn.
CYCLE_ALARMS: tuple[tuple[int, int, int, str], ...] = (
    (1004, ALARM_TYPES["EX"], 0, "COOLANT LEVEL LOW"),
    (500, ALARM_TYPES["OT"], 1, "OVER TRAVEL ( +1 )"),
    (1010, ALARM_TYPES["EX"], 0, "DOOR INTERLOCK OPEN"),
    (700, ALARM_TYPES["OH"], 0, "OVERHEAT: CONTROL UNIT"),
    (436, ALARM_TYPES["SV"], 2, "SOFTTHERMAL (OVC)"),
)

PROGRAMS: tuple[ProgramDirEntry, ...] = (
    ProgramDirEntry(1, 412, "(WARM UP)"),
    ProgramDirEntry(1234, 18_344, "(BRACKET OP10)"),
    ProgramDirEntry(1235, 9_120, "(BRACKET OP20)"),
    ProgramDirEntry(2000, 2_230, "(PROBE CYCLE)"),
    ProgramDirEntry(8000, 640, "(TOOL CHANGE SUB)"),
    ProgramDirEntry(9000, 1_024, "(MACRO LIB)"),
)


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


def _initial_macros() -> dict[int, float | None]:
    macros: dict[int, float | None] = {n: None for lo, hi in MACRO_RANGES for n in range(lo, hi + 1)}
    macros.update({100: 1.0, 101: 0.0, 110: 25.4, 500: 12.5, 501: 0.0, 502: 3.0, 503: -0.125,
                   510: 150.0, 511: 75.25, 999: 1.0})
    return macros


def _initial_pmc(profile: Profile) -> dict[str, bytearray]:
    areas = {area: bytearray(size) for area, size in profile.pmc_sizes.items()}
    areas["G"][8] = 0b0001_0000  # *ESP (G8.4) high = not in emergency stop
    areas["G"][12] = 155  # feed override *FV (negative logic)
    areas["G"][30] = 100  # spindle override SOV
    areas["X"][8] = 0b0001_0000  # *ESP input
    areas["D"][2204:2206] = (600).to_bytes(2, "big")  # the word PF's capture read back (600)
    areas["R"][100:104] = b"FOCS"
    areas["K"][0] = 0b1000_0001
    return areas


CLOCK_MACRO_MODULO = 1000.0  # a macro holds about nine digits: seconds modulo 1000 with milliseconds


def clock_macro_value(epoch_s: float) -> float:
    """What the clock macro reads at a CNC time (epoch seconds): seconds modulo 1000, to the millisecond."""
    return round(epoch_s % CLOCK_MACRO_MODULO, 3)


def clock_macro_error(stamp_s: float, value: float) -> float:
    """A source timestamp (epoch seconds) minus the CNC clock a clock macro `value` recorded, in seconds
    (-500..500: the macro wraps every 1000 s)."""
    return (stamp_s - value + CLOCK_MACRO_MODULO / 2) % CLOCK_MACRO_MODULO - CLOCK_MACRO_MODULO / 2


def _zone(name: str | tzinfo) -> tzinfo:
    return ZoneInfo(name) if isinstance(name, str) else name


class MachineState:
    """One simulated CNC. Construct with a profile (or its name) and, in tests, a fake `time_source`."""

    def __init__(
        self,
        profile: Profile | str = "30i",
        *,
        name: str = "cnc",
        time_source: Callable[[], float] = time.time,
        timezone: str | tzinfo = "UTC",
        clock_offset: float = 0.0,
        cycle: CycleSpec | None = None,
        seed: int = 0,
        start_parts: int = 0,
        path: int = 1,
    ) -> None:
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.name = name
        self.path = path
        self.cycle = cycle or CycleSpec()
        self.seed = seed
        self._time = time_source
        self._lock = threading.RLock()
        self._tz = _zone(timezone)
        self._clock_offset = float(clock_offset)
        self._t0 = self._time()
        self._phase = (seed * 7.31) % self.cycle.length  # so machines of a fleet do not run in step
        self._processed = 0.0  # cycle time (s since t0 + phase) already replayed
        self._param_specs = param_specs(self.profile)
        self._diag_specs = diag_specs(self.profile)
        self._params: dict[int, list[int | float]] = {
            number: list(spec.initial) for number, spec in self._param_specs.items()
        }
        self._params[PART_COUNT_PARAM] = [start_parts]
        self._params[TOTAL_PARTS_PARAM] = [1_000 + start_parts]
        self._macros = _initial_macros()
        self._pmc = _initial_pmc(self.profile)
        self._history: deque[AlarmEvent] = deque(maxlen=ALARM_HISTORY_SIZE)
        self._manual_alarms: list[ActiveAlarm] = []
        self._cycle_alarm: ActiveAlarm | None = None
        self.param_write_enabled = False
        # A test hook: this macro reads as the CNC's own clock at the moment it answers (clock_macro_value),
        # so a subscriber can compare a published source timestamp with the clock it claims to be.
        self.clock_macro: int | None = None
        self.emergency = False
        self.mode = AUT_MEM
        self.write_log: list[WriteRecord] = []
        self._seed_history()
        self._processed = self._phase
        self._refresh_signals(self._phase)
        # Path 1 owns the further paths of a multi-path control, each running its own program and cycle.
        self._paths: dict[int, MachineState] = {path: self}
        for other in range(2, self.profile.paths + 1) if path == 1 else ():
            cycle_of_path = replace(self.cycle, program_number=self.cycle.program_number + 1000 * (other - 1),
                                    cut_seconds=self.cycle.cut_seconds * (1 + 0.25 * (other - 1)))
            self._paths[other] = MachineState(self.profile, name=f"{name}/path{other}", time_source=time_source,
                                              timezone=timezone, clock_offset=clock_offset, cycle=cycle_of_path,
                                              seed=seed + 17 * (other - 1), start_parts=start_parts, path=other)

    def for_path(self, path: int) -> MachineState | None:
        """The state answering requests for CNC path `path` (None: the control has no such path)."""
        return self._paths.get(path)

    # ---- time --------------------------------------------------------------------------------------
    def now(self) -> float:
        """Gateway (real) time, seconds since the epoch, from the injected clock."""
        return self._time()

    def advance(self, now: float | None = None) -> None:
        """Replay the cycle up to `now` (default: the injected clock): parts, alarms raised and cleared."""
        with self._lock:
            target = (self._time() if now is None else now) - self._t0 + self._phase
            processed = self._processed
            if target <= processed:
                return
            self._count_parts(processed, target)
            if self.cycle.alarm_every > 0:
                self._replay_alarms(processed, target)
            self._processed = target
            self._refresh_signals(target)

    def _cycle_time(self) -> float:
        """Advance to now and return the cycle time (seconds since start plus this machine's phase)."""
        self.advance()
        return self._processed

    def _phase_at(self, t: float) -> tuple[bool, float]:
        """(cutting?, seconds into that phase) at cycle time t."""
        within = t % self.cycle.length
        if within < self.cycle.cut_seconds:
            return True, within
        return False, within - self.cycle.cut_seconds

    def _count_parts(self, start: float, end: float) -> None:
        length, cut = self.cycle.length, self.cycle.cut_seconds
        done = math.floor((end - cut) / length) - math.floor((start - cut) / length)
        if done > 0:
            self._params[PART_COUNT_PARAM][0] = int(self._params[PART_COUNT_PARAM][0]) + done
            self._params[TOTAL_PARTS_PARAM][0] = int(self._params[TOTAL_PARTS_PARAM][0]) + done

    def _replay_alarms(self, start: float, end: float) -> None:
        """Raise/clear the cycle alarms whose moments fall in (start, end]; at most a ring's worth."""
        length, every = self.cycle.length, self.cycle.alarm_every
        first = max(0, math.floor(start / length) - 1)
        last = math.floor(end / length)
        first = max(first, last - every * (ALARM_HISTORY_SIZE + 1))
        for k in range(first, last + 1):
            if k % every != every - 1:
                continue
            raised = k * length + self.cycle.cut_seconds + 0.5
            cleared = raised + min(self.cycle.alarm_seconds, self.cycle.idle_seconds - 0.6)
            number, atype, axis, message = CYCLE_ALARMS[(k // every) % len(CYCLE_ALARMS)]
            if start < raised <= end:
                alarm = ActiveAlarm(number, atype, axis, message)
                self._cycle_alarm = alarm
                self._record(alarm, self._t0 + raised - self._phase)
            if start < cleared <= end:
                self._cycle_alarm = None

    def _refresh_signals(self, t: float) -> None:
        """F/Y signals that mirror the machine state (a ladder would set them)."""
        cutting, _ = self._phase_at(t)
        running = cutting and not self.emergency
        f, y = self._pmc["F"], self._pmc["Y"]
        f[0] = (0b1000_0000 if self.mode == AUT_MEM else 0) | (0b0010_0000 if running else 0)
        f[1] = 0b0000_0001 if self._alarms_active() else 0  # AL
        y[0] = (y[0] & 0xFE) | (1 if running else 0)  # coolant on

    # ---- CNC clock ---------------------------------------------------------------------------------
    @property
    def timezone(self) -> tzinfo:
        return self._tz

    @timezone.setter
    def timezone(self, zone: str | tzinfo) -> None:
        with self._lock:
            self._tz = _zone(zone)

    @property
    def clock_offset(self) -> float:
        """Seconds the CNC clock runs ahead of real time (negative: behind)."""
        return self._clock_offset

    @clock_offset.setter
    def clock_offset(self, seconds: float) -> None:
        with self._lock:
            self._clock_offset = float(seconds)

    def _local_at(self, real: float) -> datetime:
        return datetime.fromtimestamp(real + self._clock_offset, self._tz).replace(tzinfo=None)

    def clock(self) -> datetime:
        """The CNC's wall clock: naive local time (real time + offset, rendered in the CNC's zone)."""
        with self._lock:
            return self._local_at(self._time())

    def clock_utc(self) -> datetime:
        """The instant the CNC clock shows, as aware UTC (what a correct collector should compute)."""
        with self._lock:
            return datetime.fromtimestamp(self._time() + self._clock_offset, UTC)

    def set_clock(self, local: datetime, protocol: str = "native") -> None:
        """Set the CNC wall clock (naive local time); the offset follows, real time does not change."""
        with self._lock:
            before = self.clock()
            aware = local.replace(tzinfo=self._tz) if local.tzinfo is None else local
            self._clock_offset = aware.timestamp() - self._time()
            self._log(protocol, "clock", before.isoformat(), local.isoformat())

    def set_time_of_day(self, hour: int, minute: int, second: int, protocol: str = "native") -> None:
        """cnc_settimer's time form: keep the CNC date, replace hour:minute:second."""
        if not (0 <= hour < 24 and 0 <= minute < 60 and 0 <= second < 60):
            raise cnc_error(EW_DATA, "cnc_settimer", message=f"time {hour}:{minute}:{second} is not valid")
        with self._lock:
            self.set_clock(self.clock().replace(hour=hour, minute=minute, second=second, microsecond=0),
                           protocol)

    def timer(self, kind: int) -> TimerValue:
        """cnc_rdtimer: 0 power-on, 1 operating, 2 cutting, 3 cycle, 4 free purpose."""
        with self._lock:
            t = self._cycle_time()
            on = self._time() - self._t0
            length, cut = self.cycle.length, self.cycle.cut_seconds
            cycles, within = divmod(t, length)
            cutting = cycles * cut + min(within, cut)
            seconds = {0: 7_406_400 + on, 1: 3_110_000 + on, 2: 1_920_000 + cutting,
                       3: within if within < cut else 0.0, 4: 0.0}.get(kind)
            if seconds is None:
                raise cnc_error(EW_NUMBER, "cnc_rdtimer", message=f"timer type {kind} is not 0..4")
            minutes, rest = divmod(seconds, 60.0)
            return TimerValue(int(minutes), int(rest * 1000))

    # ---- identity and status -----------------------------------------------------------------------
    def sysinfo(self) -> SysInfo:
        return self.profile.sysinfo

    def status(self) -> StatInfo:
        """cnc_statinfo: MEM + STaRT + MoTioN while cutting; reset between parts; ALarM while one is on."""
        with self._lock:
            cutting, into = self._phase_at(self._cycle_time())
            alarm = 1 if self._alarms_active() else 0
            if self.emergency:
                return StatInfo(self.mode, RUN_RESET, MOTION_NONE, 0, 1, alarm, 0)
            if not cutting:
                return StatInfo(self.mode, RUN_RESET, MOTION_NONE, 0, 0, alarm, 0)
            tool_change = into < 1.0  # M06 waiting for FIN at the start of the program
            dwell = 0.55 < into / self.cycle.cut_seconds < 0.6
            motion = MOTION_NONE if tool_change else MOTION_DWELL if dwell else MOTION_MOVING
            return StatInfo(self.mode, RUN_START, motion, 1 if tool_change else 0, 0, alarm, 0)

    def set_emergency(self, on: bool) -> None:
        with self._lock:
            self.emergency = on
            self._refresh_signals(self._processed)

    def set_param_write_enable(self, on: bool) -> None:
        """The PWE switch (setting screen): parameter writes answer EW_PASSWD while it is off."""
        with self._lock:
            self.param_write_enabled = on

    # ---- program -----------------------------------------------------------------------------------
    def program_numbers(self) -> ProgramNumbers:
        number = self.cycle.program_number
        return ProgramNumbers(running=number, main=number)

    def sequence_number(self) -> int:
        """N number of the executing block: climbs by 10 through the program, 0 between parts."""
        with self._lock:
            cutting, into = self._phase_at(self._cycle_time())
            return 10 + 10 * int(40 * into / self.cycle.cut_seconds) if cutting else 0

    def modal_g_codes(self) -> list[ModalGCode]:
        """The active block's modal G codes (cnc_rdgcode groups as the library indexes them, 0 = motion):
        G01 while cutting, G00 between parts; the rest fixed (plane, absolute, mm/min, metric, G54)."""
        with self._lock:
            cutting, _ = self._phase_at(self._cycle_time())
        fixed = ((1, "G17"), (2, "G90"), (4, "G94"), (5, "G21"), (6, "G40"), (7, "G49"), (8, "G80"), (13, "G54"))
        return [ModalGCode(0, "G01" if cutting else "G00"), *(ModalGCode(g, code) for g, code in fixed)]

    def tool_number(self) -> int:
        """The T code in use: one tool per quarter of the cut (T1..T4), the first tool between parts."""
        with self._lock:
            cutting, into = self._phase_at(self._cycle_time())
            return 1 + min(3, int(4 * into / self.cycle.cut_seconds)) if cutting else 1

    def exec_program(self) -> ExecProgram:
        number = self.cycle.program_number
        return ExecProgram(number, f"O{number:04d}")

    def main_program_path(self) -> str:
        return f"//CNC_MEM/USER/PATH1/O{self.cycle.program_number:04d}"

    def operator_messages(self) -> list[OperatorMessage]:
        """The message a part program shows between parts (#3006-style), none while cutting."""
        with self._lock:
            cutting, _ = self._phase_at(self._cycle_time())
            return [] if cutting else [OperatorMessage(LOAD_BLANK_MESSAGE, 0, "LOAD NEXT BLANK")]

    def tool_offsets(self, kind: int, first: int, last: int) -> list[float]:
        """Tool offsets first..last of one kind (0 length geometry, 1 length wear, 2 radius geometry,
        3 radius wear); TOOL_OFFSET_COUNT offsets exist."""
        if not 0 <= kind <= 3:
            raise cnc_error(EW_ATTRIB, "cnc_rdtofsr", message=f"offset type {kind} is not 0..3")
        if not 1 <= first <= last <= TOOL_OFFSET_COUNT:
            raise cnc_error(EW_NUMBER, "cnc_rdtofsr",
                            message=f"offsets {first}..{last} are outside 1..{TOOL_OFFSET_COUNT}")
        bases = ((100.0, 2.5), (0.0, -0.002), (5.0, 0.5), (0.0, 0.001))
        base, step = bases[kind]
        return [round(base + step * n, 4) for n in range(first, last + 1)]

    def work_offsets(self, number: int) -> list[float]:
        """Work-coordinate offset `number` (0 external, 1..6 G54..G59) for every controlled axis."""
        if not 0 <= number <= WORK_OFFSET_COUNT:
            raise cnc_error(EW_NUMBER, "cnc_rdzofs",
                            message=f"work offset {number} is outside 0..{WORK_OFFSET_COUNT}")
        if number == 0:
            return [0.0] * self.profile.axis_count
        return [round(-100.0 * (index + 1) - 10.0 * number - 0.125, 3) for index in range(self.profile.axis_count)]

    def program_directory(self, start: int = 1, count: int = 19) -> list[ProgramDirEntry]:
        """Programs numbered >= start, at most count of them (an empty list past the last)."""
        if count < 1:
            raise cnc_error(EW_LENGTH, "cnc_rdprogdir", message=f"count {count} is not positive")
        return [p for p in PROGRAMS if p.number >= start][:count]

    # ---- motion ------------------------------------------------------------------------------------
    def _axis_positions(self, t: float) -> list[float]:
        """Absolute position of every axis at cycle time t: a contour while cutting, home between parts."""
        cutting, into = self._phase_at(t)
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

    def positions(self, kind: str = "absolute") -> list[float]:
        """Per controlled axis: absolute, machine (absolute + work offset), relative, distance (to go)."""
        with self._lock:
            t = self._cycle_time()
            now = self._axis_positions(t)
            if kind in ("absolute", "relative"):
                return now
            if kind == "machine":
                offsets = (-350.0, -200.0, -410.0, 0.0, 0.0)
                return [round(v + offsets[i % len(offsets)], 3) for i, v in enumerate(now)]
            if kind == "distance":
                ahead = self._axis_positions(t + 0.25)
                return [round(a - b, 3) for a, b in zip(ahead, now, strict=True)]
            raise cnc_error(EW_NUMBER, "cnc_position", message=f"unknown position kind {kind!r}")

    def _cut_wave(self, speed: float) -> tuple[bool, float]:
        cutting, into = self._phase_at(self._cycle_time())
        return cutting and not self.emergency, math.sin(into * speed + self.seed)

    def actual_feed(self) -> float:
        """Actual feed (mm/min): 0 between parts."""
        with self._lock:
            cutting, wave = self._cut_wave(0.9)
            return float(round(1200 + 350 * wave)) if cutting else 0.0

    def spindle_speed(self) -> float:
        """Actual spindle speed (min-1)."""
        with self._lock:
            cutting, wave = self._cut_wave(0.4)
            return float(round(6000 + 150 * wave)) if cutting else 0.0

    def spindle_loads(self) -> list[float]:
        """Load meter per spindle (%)."""
        with self._lock:
            cutting, wave = self._cut_wave(1.3)
            main = round(38 + 22 * wave, 1) if cutting else 0.0
            return [main] + [round(main * 0.3, 1)] * (len(self.profile.spindle_names) - 1)

    def servo_meter(self) -> list[float]:
        """Servo load meter per axis (%)."""
        with self._lock:
            cutting, wave = self._cut_wave(1.7)
            return [round((18 + 9 * wave + 4 * i) if cutting else 2.0 + i, 1)
                    for i in range(self.profile.axis_count)]

    def axis_names(self) -> list[str]:
        return list(self.profile.axis_names)

    def spindle_names(self) -> list[str]:
        return list(self.profile.spindle_names)

    def controlled_axes(self, what: int = 2) -> int:
        """0xa4: what = 2 controlled axes, 1 spindles (0 and 3 answer the axis count too)."""
        return len(self.profile.spindle_names) if what == 1 else self.profile.axis_count

    # ---- alarms ------------------------------------------------------------------------------------
    def _alarms_active(self) -> bool:
        return bool(self._manual_alarms) or self._cycle_alarm is not None

    def active_alarms(self, max_count: int = 32) -> list[ActiveAlarm]:
        """Alarms now active (cycle alarm first), at most max_count."""
        with self._lock:
            self.advance()
            alarms = ([self._cycle_alarm] if self._cycle_alarm else []) + self._manual_alarms
            return alarms[: max(0, max_count)]

    def alarm_status(self) -> int:
        """Alarm status word: bit n set while an alarm of type n is active (0 = no alarm)."""
        bits = 0
        for alarm in self.active_alarms():
            if 0 <= alarm.type < 32:
                bits |= 1 << alarm.type
        return bits

    def alarm_history(self, depth: int = ALARM_HISTORY_SIZE) -> list[AlarmHistoryEntry]:
        """Newest first, depth clamped to 1..250; `occurred` = the CNC wall-clock fields (see AlarmEvent)."""
        return [event.entry() for event in self.alarm_events(depth)]

    def alarm_events(self, depth: int = ALARM_HISTORY_SIZE) -> list[AlarmEvent]:
        """The history ring, newest first, with both the CNC local time and the real instant."""
        with self._lock:
            self.advance()
            depth = min(max(depth, 1), ALARM_HISTORY_SIZE)
            return list(self._history)[:depth]

    def raise_alarm(self, number: int, type: int = ALARM_TYPES["EX"], axis: int = 0,
                    message: str = "") -> ActiveAlarm:
        """Make an alarm active until cleared, and record it in the history."""
        with self._lock:
            self.advance()
            alarm = ActiveAlarm(number, type, axis, message or f"ALARM {number}")
            self._manual_alarms = [a for a in self._manual_alarms if a.number != number] + [alarm]
            self._record(alarm, self._time())
            self._refresh_signals(self._processed)
            return alarm

    def clear_alarms(self, number: int | None = None) -> None:
        """Clear one raised alarm (by number) or all of them (reset), including the cycle's."""
        with self._lock:
            self.advance()
            if number is None:
                self._manual_alarms = []
                self._cycle_alarm = None
            else:
                self._manual_alarms = [a for a in self._manual_alarms if a.number != number]
                if self._cycle_alarm and self._cycle_alarm.number == number:
                    self._cycle_alarm = None
            self._refresh_signals(self._processed)

    def _record(self, alarm: ActiveAlarm, real: float) -> None:
        self._history.appendleft(AlarmEvent(
            local_time=self._local_at(real).replace(microsecond=0),
            utc_time=datetime.fromtimestamp(real, UTC),
            number=alarm.number, type=alarm.type, axis=alarm.axis, message=alarm.message))

    def _seed_history(self) -> None:
        """A few past alarms over the previous days, so a fresh machine already has a history."""
        step = 6 * 3600 + 17 * 60 + 13 * (self.seed % 5)
        for i in range(12, 0, -1):
            number, atype, axis, message = CYCLE_ALARMS[(i + self.seed) % len(CYCLE_ALARMS)]
            self._record(ActiveAlarm(number, atype, axis, message), self._t0 - i * step)

    # ---- macros ------------------------------------------------------------------------------------
    @staticmethod
    def _check_macro(number: int, function: str) -> None:
        for lo, hi in MACRO_RANGES:  # a loop, not any(): every macro read of every poll passes here
            if lo <= number <= hi:
                return
        ranges = ", ".join(f"#{lo}-#{hi}" for lo, hi in MACRO_RANGES)
        raise cnc_error(EW_NUMBER, function, message=f"macro #{number} is outside {ranges}")

    def read_macros(self, first: int, last: int) -> list[float | None]:
        """#first..#last inclusive (None = vacant); EW_NUMBER if any number is not a common variable."""
        if last < first:
            raise cnc_error(EW_NUMBER, "cnc_rdmacror", message=f"range #{first}-#{last} is empty")
        self._check_macro(first, "cnc_rdmacror")
        self._check_macro(last, "cnc_rdmacror")
        with self._lock:
            macros = self._macros
            try:
                values = [macros[n] for n in range(first, last + 1)]
            except KeyError:
                gap = f"range #{first}-#{last} spans a gap"
            else:
                clock = self.clock_macro
                if clock is not None and first <= clock <= last:
                    values[clock - first] = clock_macro_value(self._time() + self._clock_offset)
                return values
        raise cnc_error(EW_NUMBER, "cnc_rdmacror", message=gap)

    def read_macro(self, number: int) -> float | None:
        return self.read_macros(number, number)[0]

    def write_macro(self, number: int, value: float | None, protocol: str = "native") -> None:
        """Store a macro value (None makes it vacant); logged."""
        self._check_macro(number, "cnc_wrmacro")
        if value is not None and not math.isfinite(value):
            raise cnc_error(EW_DATA, "cnc_wrmacro", message=f"value {value} is not a finite number")
        with self._lock:
            old = self._macros[number]
            self._macros[number] = None if value is None else float(value)
            self._log(protocol, f"macro:{number}", old, self._macros[number])

    # ---- PMC ---------------------------------------------------------------------------------------
    def _pmc_area(self, area: str, function: str) -> bytearray:
        memory = self._pmc.get(area.upper())
        if memory is None:
            raise cnc_error(EW_ATTRIB, function,
                            message=f"PMC area {area!r} not present; areas: {''.join(self._pmc)}")
        return memory

    def pmc_size(self, area: str) -> int:
        """Bytes in a PMC area (addresses 0..size-1)."""
        return len(self._pmc_area(area, "pmc_size"))

    def read_pmc_bytes(self, area: str, start: int, end: int) -> bytes:
        """Raw bytes start..end inclusive; EW_NUMBER outside the area."""
        with self._lock:
            self.advance()
            memory = self._pmc_area(area, "pmc_rdpmcrng")
            if start < 0 or end < start or end >= len(memory):
                raise cnc_error(EW_NUMBER, "pmc_rdpmcrng", message=(
                    f"{area}{start}-{area}{end} is outside {area}0-{area}{len(memory) - 1}"))
            return bytes(memory[start : end + 1])

    def read_pmc(self, area: str, start: int, end: int,
                 data_type: PmcType | int = PmcType.BYTE) -> list[int | float]:
        """Elements of `data_type` width over bytes start..end (big-endian; bytes unsigned, words signed)."""
        try:
            kind = PmcType(data_type)
        except ValueError:
            raise cnc_error(EW_ATTRIB, "pmc_rdpmcrng", message=f"data type {data_type} unknown") from None
        if kind in (PmcType.FLOAT, PmcType.DOUBLE) and not self.profile.pmc_float_types:
            raise cnc_error(EW_ATTRIB, "pmc_rdpmcrng",
                            message=f"{self.profile.name} has no {kind.name} PMC data")
        count = (end - start + 1) // kind.width
        if count < 1:
            raise cnc_error(EW_LENGTH, "pmc_rdpmcrng", message=(
                f"{area}{start}-{area}{end} is shorter than one {kind.name} ({kind.width} bytes)"))
        raw = self.read_pmc_bytes(area, start, start + count * kind.width - 1)
        return list(struct.unpack(f">{count}{kind.struct_code}", raw))

    def write_pmc(self, area: str, start: int, data: bytes, protocol: str = "native") -> None:
        """Store 1..32 bytes at start; EW_LENGTH beyond 32 (or empty), EW_NUMBER outside the area; logged."""
        if not 1 <= len(data) <= PMC_WRITE_MAX:
            raise cnc_error(EW_LENGTH, "pmc_wrpmcrng", message=(
                f"{len(data)} bytes in one write; expected 1..{PMC_WRITE_MAX}"))
        with self._lock:
            memory = self._pmc_area(area, "pmc_wrpmcrng")
            end = start + len(data) - 1
            if start < 0 or end >= len(memory):
                raise cnc_error(EW_NUMBER, "pmc_wrpmcrng", message=(
                    f"{area}{start}-{area}{end} is outside {area}0-{area}{len(memory) - 1}"))
            old = bytes(memory[start : end + 1])
            memory[start : end + 1] = data
            target = f"pmc:{area.upper()}{start}" + (f"-{area.upper()}{end}" if end > start else "")
            self._log(protocol, target, old, bytes(data))

    # ---- parameters and diagnoses -----------------------------------------------------------------
    def param_spec(self, number: int) -> ParamSpec:
        spec = self._param_specs.get(number)
        if spec is None:
            raise cnc_error(EW_NUMBER, "cnc_rdparam", message=f"parameter {number} does not exist")
        return spec

    def read_params(self, first: int, last: int, axis: int = 0) -> list[ParamRecord]:
        """Records of the parameters that exist in first..last (EW_NUMBER if none).

        axis 0 or -1 on a per-axis parameter gives every axis (record axis -1); axis n gives slot n only;
        a non-axis parameter answers axis 0 whatever was asked. EW_ATTRIB for an axis beyond the control's.
        """
        with self._lock:
            self.advance()
            return self._records(first, last, axis, self._param_specs, self._param_values, "cnc_rdparam")

    def read_diag(self, first: int, last: int, axis: int = 0) -> list[ParamRecord]:
        """As read_params, for diagnosis numbers (values follow the running cycle)."""
        with self._lock:
            t = self._cycle_time()
            return self._records(first, last, axis, self._diag_specs,
                                 lambda number: self._diag_values(number, t), "cnc_diagnoss")

    def _param_values(self, number: int) -> list[int | float]:
        return self._params[number]

    def _records(self, first: int, last: int, axis: int, specs: dict[int, ParamSpec],
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

    def _diag_values(self, number: int, t: float) -> list[int | float]:
        cutting, into = self._phase_at(t)
        n = self.profile.axis_count
        absolute = self._axis_positions(t)
        if number == 0:
            return [0b0000_0001 if cutting and into < 1.0 else 0]  # waiting for FIN (tool change)
        if number == 300:
            return [round(v * 3.1) % 97 if cutting else 0 for v in absolute]
        if number in (308, 309):
            base = 31 if number == 308 else 29
            return [base + (6 if cutting else 0) + i for i in range(n)]
        if number == 410:
            return [int(self.spindle_loads()[0])]
        if number == 411:
            return [int(self.spindle_speed())]
        if number == 980:
            return [int(v * 1000) for v in self.positions("machine")]
        if number == 981:
            return [int(v * 1000) for v in absolute]
        if number == 982:
            return [int(v * 1000) for v in self.positions("distance")]
        raise AssertionError(f"diagnosis {number} has a spec but no value")  # pragma: no cover

    def write_param(self, number: int, axis: int, value: int | float, protocol: str = "native") -> None:
        """Write a whole parameter (bit parameters: the whole byte; clients RMW bits).

        EW_PASSWD while the parameter-write-enable switch is off; EW_NUMBER for an unknown number;
        EW_ATTRIB for an axis that does not fit (per-axis: 1..n or -1 for all; others: 0);
        EW_DATA for a value outside the parameter type's range.
        """
        with self._lock:
            if not self.param_write_enabled:
                raise cnc_error(EW_PASSWD, "cnc_wrparam",
                                message="parameter write enable (PWE) is off")
            self.set_param(number, axis, value, protocol)

    def set_param(self, number: int, axis: int, value: int | float, protocol: str = "admin") -> None:
        """As write_param, but at the panel: the parameter-write-enable switch is not consulted."""
        with self._lock:
            spec = self._param_specs.get(number)
            if spec is None:
                raise cnc_error(EW_NUMBER, "cnc_wrparam", message=f"parameter {number} does not exist")
            stored = _checked_value(spec, value)
            values = self._params[number]
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
            self._log(protocol, f"param:{number}/{axis}" if spec.per_axis else f"param:{number}", old, stored)

    def read_param_value(self, number: int, axis: int = 0) -> int | float:
        """One stored value (tests and the admin endpoint): axis 1..n for per-axis parameters."""
        with self._lock:
            self.advance()
            spec = self.param_spec(number)
            return self._params[number][axis - 1 if spec.per_axis else 0]

    @property
    def part_count(self) -> int:
        return int(self.read_param_value(PART_COUNT_PARAM))

    # ---- write log ---------------------------------------------------------------------------------
    def _log(self, protocol: str, target: str, old: object, new: object) -> None:
        self.write_log.append(WriteRecord(self._time(), protocol, target, old, new))

    def writes(self, target_prefix: str = "") -> list[WriteRecord]:
        """The write log, optionally only targets starting with `target_prefix` (e.g. "macro:")."""
        with self._lock:
            return [w for w in self.write_log if w.target.startswith(target_prefix)]

    # ---- summary -----------------------------------------------------------------------------------
    def snapshot(self) -> dict[str, object]:
        """A JSON-friendly summary (admin endpoint, CLI)."""
        with self._lock:
            status = self.status()
            return {
                "name": self.name,
                "profile": self.profile.name,
                "status": {"aut": status.aut, "run": status.run, "motion": status.motion,
                           "emergency": status.emergency, "alarm": status.alarm},
                "part_count": self.part_count,
                "active_alarms": [{"number": a.number, "type": a.type, "axis": a.axis, "message": a.message}
                                  for a in self.active_alarms()],
                "alarm_history_size": len(self._history),
                "clock": self.clock().isoformat(timespec="seconds"),
                "timezone": str(self._tz),
                "clock_offset": self._clock_offset,
                "param_write_enabled": self.param_write_enabled,
                "writes": len(self.write_log),
            }


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
