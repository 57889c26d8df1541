"""The simulated machine: one CNC's state, shared by every protocol server that serves it.

Pure model, no I/O. Time comes from an injected clock (`time_source`, seconds since the epoch), and the
machine catches up lazily: every public read first calls :meth:`MachineState.advance`, which replays the
cycle events (part finished, alarm raised, alarm cleared) between the last call and now. A test that
injects a fake clock gets exactly the same machine every run.

The cycle: a part program runs (MEM + STaRT + MoTioN, axes move, feed and spindle turn), then the machine
sits between parts (reset after M30) and the cycle repeats. FEED HOLD stops the cycle where it is until it
is released (the operator's cycle start): the status word says HOLD, the axes stand, feed and the cutting
loads are 0, no part is finished; the spindle turns on, as on a real control. The cycle time then resumes
from where it stood, so the held time is simply missing from it. Each finished part increments parameters
6711 (parts count) and 6712 (total parts). Machines with ``CycleSpec.alarm_every`` > 0 raise an alarm
between parts every that many cycles and clear it a few seconds later; every alarm enters the history
ring (250 entries, newest first) stamped with the CNC's local wall-clock time.

Methods are protocol-neutral: they take numbers and return the typed values of edge.focas.model, and
raise ``edge.focas.errors.cnc_error(code, function)`` for the conditions a real control answers with an
EW_* code (EW_NUMBER outside a range, EW_LENGTH for a PMC write over 32 bytes, EW_PASSWD for a parameter
write while the parameter-write-enable switch is off, ...). Every method is thread-safe (one RLock), so
an admin thread and the servers' event loop may share a machine.

MachineState is the one face of the machine; the state itself lives in one object per area, each in its
own module: macros (state_macros), PMC memory (state_pmc), parameters and diagnosis specs (state_params),
alarms (state_alarms), the part program and cycle (state_program), motion (state_motion), the CNC clock
(state_clock) and the write log (state_writes). The rules that hold them together:

1. Every caller goes through MachineState; nothing outside this module touches an area.
2. The areas hold no lock and never read the time: MachineState takes its one RLock around each call
   into them and passes the cycle time `t` in, after advancing, where an answer depends on it.
3. Only MachineState crosses areas: the cycle replay (parts into the parameters, alarms into the ring),
   the status word, the PMC signals mirroring the machine, the diagnosis values computed from motion.
4. Replacing `profile` (or `cycle`) reaches every area that reads it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace
from datetime import datetime, tzinfo

from edge.focas.errors import EW_PASSWD, cnc_error
from edge.focas.model import (
    ActiveAlarm,
    AlarmHistoryEntry,
    ExecProgram,
    ModalGCode,
    OperatorMessage,
    ParamRecord,
    PmcType,
    ProgramDirEntry,
    ProgramNumbers,
    StatInfo,
    SysInfo,
    TimerValue,
)
from edge.sim.profiles import Profile, get_profile
from edge.sim.state_alarms import ALARM_HISTORY_SIZE, ALARM_TYPES, AlarmEvent, Alarms
from edge.sim.state_clock import CncClock, clock_macro_value, zone
from edge.sim.state_macros import Macros
from edge.sim.state_motion import Motion
from edge.sim.state_params import PART_COUNT_PARAM, Parameters, ParamSpec
from edge.sim.state_pmc import PmcMemory
from edge.sim.state_program import (
    AUT_MEM,
    MOTION_DWELL,
    MOTION_MOVING,
    MOTION_NONE,
    RUN_HOLD,
    RUN_RESET,
    RUN_START,
    CycleSpec,
    Program,
)
from edge.sim.state_writes import WriteLog, WriteRecord


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
        self._profile = get_profile(profile) if isinstance(profile, str) else profile
        self.name = name
        self.path = path
        self._cycle = cycle or CycleSpec()
        self.seed = seed
        self._time = time_source
        self._lock = threading.RLock()
        self._t0 = self._time()
        self._phase = (seed * 7.31) % self._cycle.length  # so machines of a fleet do not run in step
        self._processed = 0.0  # cycle time (s since t0 + phase) already replayed
        self._writes = WriteLog(time_source)
        self._clock = CncClock(time_source, timezone, clock_offset, self._writes)
        self._macros = Macros(self._writes)
        self._pmc = PmcMemory(self._profile, self._writes)
        self._params = Parameters(self._profile, self._writes, start_parts)
        self._alarms = Alarms(self._clock)
        self._program = Program(self._profile, self._cycle, path)
        self._motion = Motion(self._profile, self._cycle, seed)
        self.param_write_enabled = False
        self._moment: float | None = None  # while set (pin_moment), the instant the cycle is read at
        # A test hook: this macro reads as the CNC's own clock at the moment it answers (clock_macro_value),
        # so a subscriber can compare a published source timestamp with the clock it claims to be.
        self.clock_macro: int | None = None
        self.emergency = False
        self.feed_hold = False  # the operator's FEED HOLD button (admin `feed_hold`): run HOLD until released
        self._held_at: float | None = None  # real time feed hold was pressed; the cycle time stands from there
        self._held_s = 0.0  # real seconds of the holds already released (missing from the cycle time)
        self.mode = AUT_MEM
        self._alarms.seed_history(self._t0, self.seed)
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

    @property
    def profile(self) -> Profile:
        return self._profile

    @profile.setter
    def profile(self, profile: Profile) -> None:
        with self._lock:
            self._profile = self._pmc.profile = self._params.profile = profile
            self._program.profile = self._motion.profile = profile

    @property
    def cycle(self) -> CycleSpec:
        return self._cycle

    @cycle.setter
    def cycle(self, cycle: CycleSpec) -> None:
        with self._lock:
            self._cycle = self._program.cycle = self._motion.cycle = cycle

    # ---- time --------------------------------------------------------------------------------------
    def now(self) -> float:
        """Gateway (real) time, seconds since the epoch, from the injected clock."""
        return self._time()

    def pin_moment(self) -> None:
        """Read the cycle at this one instant until unpin_moment: a server answering one request pins it, so
        the request's dozen reads replay the cycle once, not once each (the answer is the state of one moment,
        as a CNC gives it). The CNC clock keeps reading the injected clock; a write answered meanwhile replays the
        cycle to the pinned moment, microseconds behind."""
        now = self._time()
        for state in self._paths.values():
            state._moment = now

    def unpin_moment(self) -> None:
        for state in self._paths.values():
            state._moment = None

    def advance(self, now: float | None = None) -> None:
        """Replay the cycle up to `now` (default: the pinned moment, else the injected clock): parts, alarms
        raised and cleared."""
        with self._lock:
            real = now
            if real is None:
                real = self._time() if self._moment is None else self._moment
            if self._held_at is not None:  # held: the cycle stands where feed hold stopped it
                real = min(real, self._held_at)
            target = real - self._t0 - self._held_s + self._phase
            processed = self._processed
            if target <= processed:
                return
            cycle = self._cycle
            done = cycle.parts_between(processed, target)
            if done > 0:
                self._params.count_parts(done)
            if cycle.alarm_every > 0:
                self._alarms.replay(cycle, processed, target, self._t0 + self._held_s, self._phase)
            self._processed = target
            self._refresh_signals(target)

    def _cycle_time(self) -> float:
        """Advance to now and return the cycle time (seconds since start plus this machine's phase)."""
        self.advance()
        return self._processed

    def _refresh_signals(self, t: float) -> None:
        """F/Y signals that mirror the machine state (a ladder would set them)."""
        cutting, _ = self._cycle.phase_at(t)
        running = cutting and not self.emergency
        held = running and self.feed_hold
        f, y = self._pmc.areas["F"], self._pmc.areas["Y"]
        f[0] = ((0b1000_0000 if self.mode == AUT_MEM else 0) | (0b0001_0000 if held else 0)  # OP, SPL
                | (0b0010_0000 if running and not held else 0))  # STL
        f[1] = 0b0000_0001 if self._alarms.any_active() else 0  # AL
        y[0] = (y[0] & 0xFE) | (1 if running else 0)  # coolant on

    # ---- CNC clock ---------------------------------------------------------------------------------
    @property
    def timezone(self) -> tzinfo:
        return self._clock.tz

    @timezone.setter
    def timezone(self, name: str | tzinfo) -> None:
        with self._lock:
            self._clock.tz = zone(name)

    @property
    def clock_offset(self) -> float:
        """Seconds the CNC clock runs ahead of real time (negative: behind)."""
        return self._clock.offset

    @clock_offset.setter
    def clock_offset(self, seconds: float) -> None:
        with self._lock:
            self._clock.offset = float(seconds)

    def clock(self) -> datetime:
        """The CNC's wall clock: naive local time (real time + offset, rendered in the CNC's zone)."""
        with self._lock:
            return self._clock.clock()

    def clock_utc(self) -> datetime:
        """The instant the CNC clock shows, as aware UTC (what a correct collector should compute)."""
        with self._lock:
            return self._clock.clock_utc()

    def set_clock(self, local: datetime, protocol: str = "native") -> None:
        """Set the CNC wall clock (naive local time); the offset follows, real time does not change."""
        with self._lock:
            self._clock.set_clock(local, protocol)

    def set_time_of_day(self, hour: int, minute: int, second: int, protocol: str = "native") -> None:
        """cnc_settimer's time form: keep the CNC date, replace hour:minute:second."""
        with self._lock:
            self._clock.set_time_of_day(hour, minute, second, protocol)

    def timer(self, kind: int) -> TimerValue:
        """cnc_rdtimer: 0 power-on, 1 operating, 2 cutting, 3 cycle, 4 free purpose."""
        with self._lock:
            t = self._cycle_time()
            return self._program.timer(kind, t, self._time() - self._t0)

    # ---- identity and status -----------------------------------------------------------------------
    def sysinfo(self) -> SysInfo:
        return self.profile.sysinfo

    def status(self) -> StatInfo:
        """cnc_statinfo: MEM + STaRT + MoTioN while cutting; reset between parts; ALarM while one is on; HOLD
        while feed hold is pressed (the cycle stands: see set_feed_hold)."""
        with self._lock:
            cutting, into = self._cycle.phase_at(self._cycle_time())
            alarm = 1 if self._alarms.any_active() else 0
            if self.emergency:
                return StatInfo(self.mode, RUN_RESET, MOTION_NONE, 0, 1, alarm, 0)
            if self.feed_hold:
                return StatInfo(self.mode, RUN_HOLD, MOTION_NONE, 0, 0, alarm, 0)
            if not cutting:
                return StatInfo(self.mode, RUN_RESET, MOTION_NONE, 0, 0, alarm, 0)
            tool_change = into < 1.0  # M06 waiting for FIN at the start of the program
            dwell = 0.55 < into / self._cycle.cut_seconds < 0.6
            motion = MOTION_NONE if tool_change else MOTION_DWELL if dwell else MOTION_MOVING
            return StatInfo(self.mode, RUN_START, motion, 1 if tool_change else 0, 0, alarm, 0)

    def set_emergency(self, on: bool) -> None:
        with self._lock:
            self.emergency = on
            self._refresh_signals(self._processed)

    def set_feed_hold(self, on: bool) -> None:
        """Press (True) or release (False: cycle start) feed hold. While pressed the status word says HOLD and
        the cycle stands: axes still, feed 0, no part finished; on release it goes on from where it stood."""
        with self._lock:
            if on and self._held_at is None:
                self.advance()  # what happened before the press still counts
                self._held_at = self._time()
            elif not on and self._held_at is not None:
                self._held_s += max(0.0, self._time() - self._held_at)
                self._held_at = None
            self.feed_hold = on
            self._refresh_signals(self._processed)

    def set_param_write_enable(self, on: bool) -> None:
        """The PWE switch (setting screen): parameter writes answer EW_PASSWD while it is off."""
        with self._lock:
            self.param_write_enabled = on

    # ---- program -----------------------------------------------------------------------------------
    def program_numbers(self) -> ProgramNumbers:
        return self._program.program_numbers()

    def sequence_number(self) -> int:
        """N number of the executing block: climbs by 10 through the program, 0 between parts."""
        with self._lock:
            return self._program.sequence_number(self._cycle_time())

    def modal_g_codes(self) -> list[ModalGCode]:
        """The active block's modal G codes (cnc_rdgcode groups as the library indexes them, 0 = motion):
        G01 while cutting, G00 between parts; the rest fixed (plane, absolute, mm/min, metric, G54)."""
        with self._lock:
            t = self._cycle_time()
        return self._program.modal_g_codes(t)

    def tool_number(self) -> int:
        """The T code in use: one tool per quarter of the cut (T1..T4), the first tool between parts."""
        with self._lock:
            return self._program.tool_number(self._cycle_time())

    def exec_program(self) -> ExecProgram:
        return self._program.exec_program()

    def main_program_path(self) -> str:
        return self._program.main_program_path()

    def operator_messages(self) -> list[OperatorMessage]:
        """The message a part program shows between parts (#3006-style), none while cutting."""
        with self._lock:
            return self._program.operator_messages(self._cycle_time())

    def tool_offsets(self, kind: int, first: int, last: int) -> list[float]:
        """Tool offsets first..last of one kind (0 length geometry, 1 length wear, 2 radius geometry,
        3 radius wear); TOOL_OFFSET_COUNT offsets exist."""
        return self._program.tool_offsets(kind, first, last)

    def work_offsets(self, number: int) -> list[float]:
        """Work-coordinate offset `number` (0 external, 1..6 G54..G59) for every controlled axis."""
        return self._program.work_offsets(number)

    def program_directory(self, start: int = 1, count: int = 19) -> list[ProgramDirEntry]:
        """Programs numbered >= start, at most count of them (an empty list past the last)."""
        return self._program.program_directory(start, count)

    # ---- motion ------------------------------------------------------------------------------------
    def positions(self, kind: str = "absolute") -> list[float]:
        """Per controlled axis: absolute, machine (absolute + work offset), relative, distance (to go)."""
        with self._lock:
            return self._motion.positions(kind, self._cycle_time())

    def actual_feed(self) -> float:
        """Actual feed (mm/min): 0 between parts and in feed hold."""
        with self._lock:
            return self._motion.actual_feed(self._cycle_time(), self.emergency or self.feed_hold)

    def spindle_speed(self) -> float:
        """Actual spindle speed (min-1)."""
        with self._lock:
            return self._motion.spindle_speed(self._cycle_time(), self.emergency)

    def spindle_loads(self) -> list[float]:
        """Load meter per spindle (%): no cutting load in feed hold (the spindle turns, nothing is cut)."""
        with self._lock:
            return self._motion.spindle_loads(self._cycle_time(), self.emergency or self.feed_hold)

    def servo_meter(self) -> list[float]:
        """Servo load meter per axis (%): idle in feed hold."""
        with self._lock:
            return self._motion.servo_meter(self._cycle_time(), self.emergency or self.feed_hold)

    def axis_names(self) -> list[str]:
        return list(self.profile.axis_names)

    def spindle_names(self) -> list[str]:
        return list(self.profile.spindle_names)

    def controlled_axes(self, what: int = 2) -> int:
        """0xa4: what = 2 controlled axes, 1 spindles (0 and 3 answer the axis count too)."""
        return len(self.profile.spindle_names) if what == 1 else self.profile.axis_count

    # ---- alarms ------------------------------------------------------------------------------------
    def active_alarms(self, max_count: int = 32) -> list[ActiveAlarm]:
        """Alarms now active (cycle alarm first), at most max_count."""
        with self._lock:
            self.advance()
            return self._alarms.active(max_count)

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
            return self._alarms.events(depth)

    def raise_alarm(self, number: int, type: int = ALARM_TYPES["EX"], axis: int = 0,
                    message: str = "") -> ActiveAlarm:
        """Make an alarm active until cleared, and record it in the history."""
        with self._lock:
            self.advance()
            alarm = self._alarms.raise_alarm(number, type, axis, message, self._time())
            self._refresh_signals(self._processed)
            return alarm

    def clear_alarms(self, number: int | None = None) -> None:
        """Clear one raised alarm (by number) or all of them (reset), including the cycle's."""
        with self._lock:
            self.advance()
            self._alarms.clear(number)
            self._refresh_signals(self._processed)

    # ---- macros ------------------------------------------------------------------------------------
    def read_macros(self, first: int, last: int) -> list[float | None]:
        """#first..#last inclusive (None = vacant); EW_NUMBER if any number is not a common variable."""
        with self._lock:
            values = self._macros.read(first, last)
            clock = self.clock_macro
            if clock is not None and first <= clock <= last:
                values[clock - first] = clock_macro_value(self._clock.epoch())
            return values

    def read_macro(self, number: int) -> float | None:
        return self.read_macros(number, number)[0]

    def write_macro(self, number: int, value: float | None, protocol: str = "native") -> None:
        """Store a macro value (None makes it vacant); logged."""
        with self._lock:
            self._macros.write(number, value, protocol)

    # ---- PMC ---------------------------------------------------------------------------------------
    def pmc_size(self, area: str) -> int:
        """Bytes in a PMC area (addresses 0..size-1)."""
        return len(self._pmc.area(area, "pmc_size"))

    def read_pmc_bytes(self, area: str, start: int, end: int) -> bytes:
        """Raw bytes start..end inclusive; EW_NUMBER outside the area."""
        with self._lock:
            self.advance()
            return self._pmc.read_bytes(area, start, end)

    def read_pmc(self, area: str, start: int, end: int,
                 data_type: PmcType | int = PmcType.BYTE) -> list[int | float]:
        """Elements of `data_type` width over bytes start..end (big-endian; bytes unsigned, words signed)."""
        with self._lock:
            self.advance()
            return self._pmc.read(area, start, end, data_type)

    def write_pmc(self, area: str, start: int, data: bytes, protocol: str = "native") -> None:
        """Store 1..32 bytes at start; EW_LENGTH beyond 32 (or empty), EW_NUMBER outside the area; logged."""
        with self._lock:
            self._pmc.write(area, start, data, protocol)

    # ---- parameters and diagnoses -----------------------------------------------------------------
    def param_spec(self, number: int) -> ParamSpec:
        return self._params.spec(number)

    def read_params(self, first: int, last: int, axis: int = 0) -> list[ParamRecord]:
        """Records of the parameters that exist in first..last (EW_NUMBER if none).

        axis 0 or -1 on a per-axis parameter gives every axis (record axis -1); axis n gives slot n only;
        a non-axis parameter answers axis 0 whatever was asked. EW_ATTRIB for an axis beyond the control's.
        """
        with self._lock:
            self.advance()
            return self._params.param_records(first, last, axis)

    def read_diag(self, first: int, last: int, axis: int = 0) -> list[ParamRecord]:
        """As read_params, for diagnosis numbers (values follow the running cycle)."""
        with self._lock:
            t = self._cycle_time()
            return self._params.diag_records(first, last, axis, lambda number: self._diag_values(number, t))

    def _diag_values(self, number: int, t: float) -> list[int | float]:
        cutting, into = self._cycle.phase_at(t)
        n = self.profile.axis_count
        absolute = self._motion.axis_positions(t)
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
            self._params.set(number, axis, value, protocol)

    def read_param_value(self, number: int, axis: int = 0) -> int | float:
        """One stored value (tests and the admin endpoint): axis 1..n for per-axis parameters."""
        with self._lock:
            self.advance()
            return self._params.value(number, axis)

    @property
    def part_count(self) -> int:
        return int(self.read_param_value(PART_COUNT_PARAM))

    # ---- write log ---------------------------------------------------------------------------------
    @property
    def write_log(self) -> list[WriteRecord]:
        """Every accepted write, oldest first."""
        return self._writes.records

    def writes(self, target_prefix: str = "") -> list[WriteRecord]:
        """The write log, optionally only targets starting with `target_prefix` (e.g. "macro:")."""
        with self._lock:
            return self._writes.matching(target_prefix)

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
                "alarm_history_size": len(self._alarms.history),
                "clock": self.clock().isoformat(timespec="seconds"),
                "timezone": str(self.timezone),
                "clock_offset": self.clock_offset,
                "param_write_enabled": self.param_write_enabled,
                "writes": len(self.write_log),
            }
