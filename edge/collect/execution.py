"""The machine's state in the MES vocabulary (MTConnect Execution and ControllerMode), from the status word.

Every subscriber asking "is it cutting, waiting or down" used to derive that from `Status/Run`, `Status/Mode`
... each its own way. The derivation lives here, as ONE table per vocabulary; docs/topics.md ("Derived
state") prints the same rows with their evidence, and tests/unit/collect/test_execution.py checks every row.

What cnc_statinfo (0x19, shared/docs/focas-protocol.md §3.4) cannot tell apart is not guessed: run STOP is the
same word after M00, after M01 with optional stop on and at the end of a single block, so it is INTERRUPTED,
never PROGRAM_STOPPED or OPTIONAL_STOP; M30 ends in RESET (READY), never PROGRAM_COMPLETED; the single-block
switch is not in the word, so SEMI_AUTOMATIC never appears.

Derivation runs only when the status word changed (the poller hands a read's values on only then), and the
answer per distinct word is remembered: the cost per changed word is one dict lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

from edge.focas.model import StatInfo
from edge.samples import MetricSpec, MetricType

# statinfo codes (16/18/21/0i/30i, shared/docs/focas-protocol.md §3.4).
RUN_RESET, RUN_STOP, RUN_HOLD, RUN_START, RUN_MSTR = 0, 1, 2, 3, 4
ALARM_ALM, ALARM_PMC = 1, 8  # the alarm codes that stop the machine; 2..7 are warnings (battery, fan ...)
EMERGENCY_EMG = 1
MSTB_FIN = 1

EXECUTION = MetricSpec("Status/Execution", MetricType.STRING,
                       description="MTConnect Execution derived from the status word (docs/topics.md)")
CONTROLLER_MODE = MetricSpec("Status/ControllerMode", MetricType.STRING,
                             description="MTConnect ControllerMode derived from the status word (docs/topics.md)")
AVAILABILITY = MetricSpec("Status/Availability", MetricType.STRING,
                          description="AVAILABLE while the CNC session is up, UNAVAILABLE when it drops")
AVAILABLE, UNAVAILABLE = "AVAILABLE", "UNAVAILABLE"


@dataclass(frozen=True, slots=True)
class ExecutionRow:
    """One row: the status-word fields it matches (None: any value) and what it means. First match wins."""

    execution: str
    run: frozenset[int] | None = None
    mstb: frozenset[int] | None = None
    alarm: frozenset[int] | None = None
    emergency: frozenset[int] | None = None
    evidence: str = ""

    def matches(self, stat: StatInfo) -> bool:
        return ((self.emergency is None or stat.emergency in self.emergency)
                and (self.alarm is None or stat.alarm in self.alarm)
                and (self.run is None or stat.run in self.run)
                and (self.mstb is None or stat.mstb in self.mstb))


_ALARMS = frozenset({ALARM_ALM, ALARM_PMC})

# THE execution table (docs/topics.md "Derived state" prints it). Motion (MTN/DWL) does not change the answer:
# a dwell is part of the program, and a START without motion is the control computing or waiting on the spindle.
EXECUTION_TABLE: tuple[ExecutionRow, ...] = (
    ExecutionRow("STOPPED", emergency=frozenset({EMERGENCY_EMG}),
                 evidence="emergency 1 EMG: the control is held in reset until the emergency stop is released"),
    ExecutionRow("STOPPED", alarm=_ALARMS, run=frozenset({RUN_RESET, RUN_STOP}),
                 evidence="alarm 1 ALM / 8 PMC with no program running: cycle start is refused until reset"),
    ExecutionRow("WAIT", run=frozenset({RUN_START}), mstb=frozenset({MSTB_FIN}),
                 evidence="run 3 STaRT with mstb 1 FIN: an M/S/T/B function (a tool change) waits for its finish"),
    ExecutionRow("ACTIVE", run=frozenset({RUN_START}),
                 evidence="run 3 STaRT: automatic operation (motion MTN, dwell DWL or computing)"),
    ExecutionRow("ACTIVE", run=frozenset({RUN_MSTR}),
                 evidence="run 4 MSTR: manual numerical command / tool retract and recover moving"),
    ExecutionRow("FEED_HOLD", run=frozenset({RUN_HOLD}),
                 evidence="run 2 HOLD: feed hold, the axes stopped where they are, cycle start resumes"),
    ExecutionRow("INTERRUPTED", run=frozenset({RUN_STOP}),
                 evidence="run 1 STOP: stopped inside a program (M00, M01, single block: the word does not say "
                          "which), cycle start resumes"),
    ExecutionRow("READY", run=frozenset({RUN_RESET}),
                 evidence="run 0 RESET: no program running (after reset or M30), ready for cycle start"),
    ExecutionRow("UNAVAILABLE", evidence="a run code outside 0..4: not a state this table knows"),
)

# aut code -> ControllerMode. 2 (****) is "no mode selected"; 10 RMT runs a program fed from outside (DNC).
CONTROLLER_MODE_TABLE: dict[int, str] = {
    0: "MANUAL_DATA_INPUT", 1: "AUTOMATIC", 2: "UNAVAILABLE", 3: "EDIT", 4: "MANUAL", 5: "MANUAL", 6: "MANUAL",
    7: "MANUAL", 8: "MANUAL", 9: "MANUAL", 10: "AUTOMATIC",
}

# Utilisation counts a status word as EMERGENCY, else ALARM, else by its Execution (UNAVAILABLE as UNKNOWN);
# a session that is down counts as OFFLINE and time the gateway did not run as UNKNOWN (edge.collect.utilisation).
OFFLINE, ALARM, EMERGENCY, UNKNOWN = "OFFLINE", "ALARM", "EMERGENCY", "UNKNOWN"


@dataclass(frozen=True, slots=True)
class DerivedState:
    """What one status word means: Execution, ControllerMode, and the utilisation state it counts as."""

    execution: str
    controller_mode: str
    counts_as: str


def execution_of(stat: StatInfo) -> str:
    """The Execution of the first table row matching `stat`."""
    for row in EXECUTION_TABLE:
        if row.matches(stat):
            return row.execution
    raise AssertionError("the table's last row matches every status word")


def derive(stat: StatInfo) -> DerivedState:
    """Execution, ControllerMode and the utilisation state of one status word (remembered per word)."""
    found = _derived.get(stat)
    if found is None:
        execution = execution_of(stat)
        counts_as = (EMERGENCY if stat.emergency == EMERGENCY_EMG else ALARM if stat.alarm in _ALARMS
                     else UNKNOWN if execution == UNAVAILABLE else execution)
        found = DerivedState(execution, CONTROLLER_MODE_TABLE.get(stat.aut, UNAVAILABLE), counts_as)
        if len(_derived) >= _MAX_REMEMBERED:  # a control answering ever new words (edit codes): stay bounded
            _derived.clear()
        _derived[stat] = found
    return found


_MAX_REMEMBERED = 4096
_derived: dict[StatInfo, DerivedState] = {}

# Every state utilisation can count, in the order they are published (the table's, then the gateway's own).
UTILISATION_STATES: tuple[str, ...] = (
    *dict.fromkeys(row.execution for row in EXECUTION_TABLE if row.execution != UNAVAILABLE),
    ALARM, EMERGENCY, OFFLINE, UNKNOWN)
