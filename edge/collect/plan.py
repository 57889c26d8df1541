"""A machine's poll plan: which reads belong to which group, when each group is due, and the metrics.

Declarative on purpose: the tables below say which read item feeds which metric (name, type, unit)
and how its value is picked out; the poller only asks `due(now)`, batches `reads_for(groups)` into one
request, and turns each result into values with `metric_values`.

Metric names use Sparkplug folders: `Status/Run`, `Program/Number`, `Spindle/1/Speed`,
`Axis/X/Absolute`, `Macro/500`, `PMC/D2204`, `Alarm/Active`, `Counters/Parts`, `Clock/Skew` ...
Axis and spindle names are only known after the static reads, so the full plan is built per session
with `MachinePlan.build(poll, static)` from the machine's poll settings (edge.collect.settings).
"""

from __future__ import annotations

import enum
import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from edge.collect.clock import SYNC_TARGET_S
from edge.collect.execution import CONTROLLER_MODE, EXECUTION, derive
from edge.collect.settings import Periods, PollSettings
from edge.focas import items as it
from edge.focas.model import ActiveAlarm, PmcType, StatInfo, SysInfo
from edge.focas.values import ALL_AXES
from edge.samples import MetricSpec, MetricType

PART_COUNT_PARAM = 6711


class Group(enum.Enum):
    """Poll groups; each has its own period (static: once per connection)."""

    STATIC = "static"
    STATUS = "status"
    ACTIVE_ALARMS = "active_alarms"  # read with the status tick, only when the alarm status changed
    MACROS = "macros"
    PMC = "pmc"
    PARAMS = "params"
    DIAGS = "diags"
    LOADS = "loads"
    COUNTERS = "counters"
    ALARM_HISTORY = "alarm_history"

    # Identity hash, in C (Enum's is Python code): the schedule hashes groups on every tick.
    __hash__ = object.__hash__


# ---- value tables ------------------------------------------------------------------------------------------

# cnc_statinfo codes (16/18/21/0i/30i) as the short texts FANUC screens show.
MODE_NAMES = {0: "MDI", 1: "MEM", 2: "****", 3: "EDIT", 4: "HND", 5: "JOG", 6: "TJOG", 7: "THND",
              8: "INC", 9: "REF", 10: "RMT"}
RUN_NAMES = {0: "RESET", 1: "STOP", 2: "HOLD", 3: "START", 4: "MSTR"}
MOTION_NAMES = {0: "", 1: "MTN", 2: "DWL"}
EMERGENCY_NAMES = {0: "", 1: "EMG", 2: "RESET"}
ALARM_NAMES = {0: "", 1: "ALM", 2: "BAT", 3: "FAN", 4: "PS", 5: "FSSB", 6: "INSULATE", 7: "ENCODER", 8: "PMC"}
POSITION_FOLDERS = {"absolute": "Absolute", "machine": "Machine", "relative": "Relative",
                    "distance": "DistanceToGo"}
PMC_METRIC_TYPES = {PmcType.BYTE: MetricType.UINT8, PmcType.WORD: MetricType.INT16,
                    PmcType.LONG: MetricType.INT32, PmcType.FLOAT: MetricType.FLOAT,
                    PmcType.DOUBLE: MetricType.DOUBLE}
ROTARY_AXES = frozenset("ABC")


def _name(table: dict[int, str], code: int) -> str:
    return table.get(code, str(code))


STATUS_METRICS: tuple[tuple[MetricSpec, Callable[[StatInfo], object]], ...] = (
    (MetricSpec("Status/Mode", MetricType.STRING, description="automatic/manual mode"),
     lambda s: _name(MODE_NAMES, s.aut)),
    (MetricSpec("Status/Run", MetricType.STRING, description="run state"), lambda s: _name(RUN_NAMES, s.run)),
    (MetricSpec("Status/Motion", MetricType.STRING), lambda s: _name(MOTION_NAMES, s.motion)),
    (MetricSpec("Status/Emergency", MetricType.BOOLEAN), lambda s: s.emergency == 1),
    (MetricSpec("Status/Alarm", MetricType.STRING), lambda s: _name(ALARM_NAMES, s.alarm)),
    (MetricSpec("Status/Edit", MetricType.INT16), lambda s: s.edit),
    (MetricSpec("Status/MSTB", MetricType.BOOLEAN, description="M/S/T/B function finishing"),
     lambda s: s.mstb == 1),
    (EXECUTION, lambda s: derive(s).execution),  # the MES vocabulary, edge.collect.execution
    (CONTROLLER_MODE, lambda s: derive(s).controller_mode),
)

SYSINFO_METRICS: tuple[tuple[MetricSpec, Callable[[SysInfo], object]], ...] = (
    (MetricSpec("Device/Model", MetricType.STRING), lambda s: s.model_name),
    (MetricSpec("Device/Series", MetricType.STRING), lambda s: s.series),
    (MetricSpec("Device/Version", MetricType.STRING), lambda s: s.version),
    (MetricSpec("Device/MaxAxis", MetricType.INT16), lambda s: s.max_axis),
)

CLOCK_SKEW = MetricSpec("Clock/Skew", MetricType.DOUBLE, "s", description="CNC minus gateway time")
CLOCK_GATEWAY = MetricSpec("Clock/UsingGatewayTime", MetricType.BOOLEAN,
                           description="true while the CNC clock is beyond max_skew_s")
CLOCK_UNCERTAINTY = MetricSpec("Clock/OffsetUncertainty", MetricType.DOUBLE, "ms",
                               description="how far a CNC timestamp can be off (half the offset interval)")
CLOCK_SYNCHRONISED = MetricSpec("Clock/Synchronised", MetricType.BOOLEAN,
                                description=f"true while CNC timestamps are within {SYNC_TARGET_S * 1000:g} ms of the "
                                            "CNC clock")
ALARM_ACTIVE = MetricSpec("Alarm/Active", MetricType.STRING, description="JSON list of active alarms")
ALARM_COUNT = MetricSpec("Alarm/Count", MetricType.INT32)
ALARM_EVENT = MetricSpec("Alarm/Event", MetricType.STRING, description="JSON raise/clear event")
ALARM_HISTORY = MetricSpec("Alarm/History", MetricType.STRING, description="JSON alarm history entry")
ALARM_STATUS = MetricSpec("Alarm/Status", MetricType.UINT32, description="alarm status bits")
PART_COUNT = MetricSpec("Counters/Parts", MetricType.INT64, description="parameter 6711")
PART_TOTAL_PARAM = 6712
PART_REQUIRED_PARAM = 6713
PART_TOTAL = MetricSpec("Counters/PartsTotal", MetricType.INT64, description="parameter 6712")
PART_REQUIRED = MetricSpec("Counters/PartsRequired", MetricType.INT64, description="parameter 6713")
PROGRAM_NAME = MetricSpec("Program/Name", MetricType.STRING, description="running program (cnc_exeprgname)")
PROGRAM_MAIN_PATH = MetricSpec("Program/MainPath", MetricType.STRING, description="main program (cnc_pdf_rdmain)")
# cnc_rdtimer types 0..3 (4, the free-purpose timer, is not a plant figure).
TIMER_FOLDERS = ("PowerOn", "Operating", "Cutting", "Cycle")
OPERATOR_MESSAGE = MetricSpec("Message/Operator", MetricType.STRING,
                              description="JSON list of operator messages (cnc_rdopmsg)")
TOOL_OFFSET_FOLDERS = ("LengthGeometry", "LengthWear", "RadiusGeometry", "RadiusWear")  # 0x08 type 0..3
TIMER_METRICS = tuple(MetricSpec(f"Times/{name}", MetricType.DOUBLE, "s", description=f"cnc_rdtimer type {kind}")
                      for kind, name in enumerate(TIMER_FOLDERS))
AXIS_NAMES = MetricSpec("Device/AxisNames", MetricType.STRING)
SPINDLE_NAMES = MetricSpec("Device/SpindleNames", MetricType.STRING)

# Metrics the collector fills itself (not from one read item).
CLOCK_METRICS = (CLOCK_SKEW, CLOCK_GATEWAY, CLOCK_UNCERTAINTY, CLOCK_SYNCHRONISED)
EVENT_METRICS = (ALARM_EVENT,)


# ---- the plan ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class StaticInfo:
    """What the static reads told us about this control, needed to name axis and spindle metrics."""

    sysinfo: SysInfo | None = None
    axis_names: tuple[str, ...] = ()
    spindle_names: tuple[str, ...] = ()
    # Configured axis-0 numbers the control answered as axis-type ("Param", 1850): read for every axis.
    per_axis: frozenset[tuple[str, int]] = frozenset()


@dataclass(frozen=True, slots=True)
class PlannedRead:
    """One read item, its group, and the metrics its result feeds (in the order metric_values returns)."""

    group: Group
    item: it.ReadItem
    metrics: tuple[MetricSpec, ...]
    deadbands: tuple[float, ...] = ()
    bits: bool = False  # a PMC byte range published bit by bit (bit 0 first)

    def deadband_map(self) -> dict[str, float]:
        return {m.name: d for m, d in zip(self.metrics, self.deadbands, strict=False) if d}


@dataclass(frozen=True, slots=True)
class MachinePlan:
    """Every read of one machine grouped, with the periods (seconds) of the groups."""

    reads: tuple[PlannedRead, ...]
    periods: dict[Group, float] = field(default_factory=dict)

    @classmethod
    def build(cls, poll: PollSettings, static: StaticInfo | None = None) -> MachinePlan:
        """A fresh plan (the poller tells sessions apart by its identity) around reads shared by every machine
        with the same poll settings and static answers: the reads and their metric specs are most of a plan's
        memory, and a fleet of one model would otherwise hold a copy per machine."""
        static = static or StaticInfo()
        key = (poll, static)
        reads = _SHARED_READS.get(key)
        if reads is None:
            if len(_SHARED_READS) >= SHARED_READS_LIMIT:
                _SHARED_READS.clear()
            reads = _SHARED_READS[key] = _build_reads(poll, static)
        return cls(reads, _group_periods(poll.periods))

    def reads_for(self, groups: Iterable[Group]) -> list[PlannedRead]:
        """The reads of `groups`, in plan order (the poller adds ReadClock to every batch)."""
        wanted = set(groups)
        return [read for read in self.reads if read.group in wanted]

    def without(self, key: str) -> MachinePlan:
        """The plan minus the reads of one drop key or operation (a function this control refuses)."""
        return MachinePlan(tuple(r for r in self.reads if key not in (r.item.operation, drop_key(r.item))),
                           self.periods)

    def metrics(self) -> list[MetricSpec]:
        """Every metric this machine can publish (for its DBIRTH), names unique."""
        seen: dict[str, MetricSpec] = {}
        for read in self.reads:
            if read.group is not Group.STATIC or read.item.operation == "ReadSysInfo":
                for spec in read.metrics:
                    seen.setdefault(spec.name, spec)
        for spec in (*CLOCK_METRICS, *EVENT_METRICS):
            seen.setdefault(spec.name, spec)
        return list(seen.values())

    def deadbands(self) -> dict[str, float]:
        bands: dict[str, float] = {}
        for read in self.reads:
            bands.update(read.deadband_map())
        return bands


def _group_periods(periods: Periods) -> dict[Group, float]:
    """Each group's period: one dict per distinct `Periods`, shared by the plans (nothing changes it)."""
    found = _GROUP_PERIODS.get(periods)
    if found is None:
        if len(_GROUP_PERIODS) >= SHARED_READS_LIMIT:
            _GROUP_PERIODS.clear()
        found = _GROUP_PERIODS[periods] = {
            Group.STATUS: periods.status, Group.ACTIVE_ALARMS: periods.status, Group.MACROS: periods.macros,
            Group.PMC: periods.pmc, Group.PARAMS: periods.params, Group.DIAGS: periods.diags,
            Group.LOADS: periods.loads, Group.COUNTERS: periods.counters, Group.ALARM_HISTORY: periods.alarm_history}
    return found


SHARED_READS_LIMIT = 256  # distinct (poll settings, static answers) pairs kept; a fleet has a few models
_SHARED_READS: dict[tuple[PollSettings, StaticInfo], tuple[PlannedRead, ...]] = {}
_GROUP_PERIODS: dict[Periods, dict[Group, float]] = {}


def _build_reads(poll: PollSettings, static: StaticInfo) -> tuple[PlannedRead, ...]:
    reads = [*_static_reads(), *_status_reads(poll.positions, poll.part_count, static)]
    reads += (_program_reads(poll) + _load_reads(poll, static) + _counter_reads(poll)
              + _work_offset_reads(poll, static) + _library_reads(poll))
    reads.append(PlannedRead(Group.ACTIVE_ALARMS, it.ReadActiveAlarms(), (ALARM_ACTIVE, ALARM_COUNT)))
    reads += _macro_reads(poll)
    reads += _pmc_reads(poll)
    reads += _numbered_reads(poll, static)
    if poll.alarm_history:
        reads.append(PlannedRead(Group.ALARM_HISTORY, it.ReadAlarmHistory(poll.alarm_history_depth),
                                 (ALARM_HISTORY,)))
    return tuple(reads)


def drop_key(item: it.ReadItem) -> str:
    """What a refused read is dropped by: its operation, or for one part of a family answered per part
    (a position kind, a timer kind) operation:part, so a control refusing one kind keeps the others."""
    match item:
        case it.ReadPositions(kind=kind):
            return f"{item.operation}:{kind}"
        case it.ReadTimer(kind=kind) | it.ReadToolOffsets(kind=kind):
            return f"{item.operation}:{kind}"
        case it.ReadWorkOffsets(number=number):
            return f"{item.operation}:{number}"
    return item.operation


def _static_reads() -> list[PlannedRead]:
    return [
        PlannedRead(Group.STATIC, it.ReadSysInfo(), tuple(spec for spec, _ in SYSINFO_METRICS)),
        PlannedRead(Group.STATIC, it.ReadAxisNames(), (AXIS_NAMES,)),
        PlannedRead(Group.STATIC, it.ReadSpindleNames(), (SPINDLE_NAMES,)),
    ]


def _status_reads(positions: Sequence[str], part_count: bool, static: StaticInfo) -> list[PlannedRead]:
    spindles = range(1, len(static.spindle_names or ("1",)) + 1)
    status = Group.STATUS
    reads = [
        PlannedRead(status, it.ReadStatus(), tuple(spec for spec, _ in STATUS_METRICS)),
        PlannedRead(status, it.ReadAlarmStatus(), (ALARM_STATUS,)),
        PlannedRead(status, it.ReadProgramNumber(), (MetricSpec("Program/Number", MetricType.INT32),
                                                     MetricSpec("Program/Main", MetricType.INT32))),
        PlannedRead(status, it.ReadSequenceNumber(), (MetricSpec("Program/Sequence", MetricType.INT32),)),
        PlannedRead(status, it.ReadFeed(), (MetricSpec("Feed/Actual", MetricType.DOUBLE, "mm/min"),)),
        PlannedRead(status, it.ReadSpindleSpeed(),
                    (MetricSpec("Spindle/1/Speed", MetricType.DOUBLE, "rpm"),)),
        PlannedRead(status, it.ReadSpindleLoad(),
                    tuple(MetricSpec(f"Spindle/{i}/Load", MetricType.DOUBLE, "%") for i in spindles)),
    ]
    for kind in positions:
        specs = tuple(MetricSpec(f"Axis/{axis}/{POSITION_FOLDERS[kind]}", MetricType.DOUBLE, axis_unit(axis))
                      for axis in static.axis_names)
        reads.append(PlannedRead(Group.STATUS, it.ReadPositions(kind), specs))
    if part_count:
        part_count_read = it.ReadParams(PART_COUNT_PARAM, PART_COUNT_PARAM)
        reads.append(PlannedRead(Group.STATUS, part_count_read, (PART_COUNT,)))
    return reads


def _program_reads(poll: PollSettings) -> list[PlannedRead]:
    reads = []
    if poll.program_name:
        reads += [PlannedRead(Group.STATUS, it.ReadExecProgramName(), (PROGRAM_NAME,)),
                  PlannedRead(Group.STATUS, it.ReadMainProgramPath(), (PROGRAM_MAIN_PATH,))]
    if poll.operator_messages:
        reads.append(PlannedRead(Group.STATUS, it.ReadOperatorMessages(), (OPERATOR_MESSAGE,)))
    return reads


def _load_reads(poll: PollSettings, static: StaticInfo) -> list[PlannedRead]:
    if not poll.servo_load or not static.axis_names:
        return []
    specs = tuple(MetricSpec(f"Axis/{axis}/Load", MetricType.DOUBLE, "%", description="servo load meter")
                  for axis in static.axis_names)
    return [PlannedRead(Group.LOADS, it.ReadServoMeter(), specs)]


def _counter_reads(poll: PollSettings) -> list[PlannedRead]:
    reads = []
    if poll.timers:
        reads += [PlannedRead(Group.COUNTERS, it.ReadTimer(kind), (spec,)) for kind, spec in enumerate(TIMER_METRICS)]
    count = poll.tool_offsets
    for kind, folder in enumerate(TOOL_OFFSET_FOLDERS) if count else ():
        specs = tuple(MetricSpec(f"Tool/{n}/{folder}", MetricType.DOUBLE) for n in range(1, count + 1))
        reads.append(PlannedRead(Group.COUNTERS, it.ReadToolOffsets(kind, 1, count), specs))
    if poll.part_count:
        reads += [PlannedRead(Group.COUNTERS, it.ReadParams(number, number), (spec,))
                  for number, spec in ((PART_TOTAL_PARAM, PART_TOTAL), (PART_REQUIRED_PARAM, PART_REQUIRED))]
    return reads


MODAL_G = MetricSpec("Modal/G", MetricType.STRING,
                     description='modal G codes of the active block, JSON {"<group>": "<code>"} (FOCAS library)')
TOOL_NUMBER = MetricSpec("Tool/Number", MetricType.INT32, description="T code in use (FOCAS library)")


def _library_reads(poll: PollSettings) -> list[PlannedRead]:
    """Opt-in reads only the FOCAS library host serves (no public native wire form), at the counters period."""
    reads = []
    if poll.modal:
        reads.append(PlannedRead(Group.COUNTERS, it.ReadModalGCodes(), (MODAL_G,)))
    if poll.tool_number:
        reads.append(PlannedRead(Group.COUNTERS, it.ReadToolNumber(), (TOOL_NUMBER,)))
    return reads


def _work_offset_reads(poll: PollSettings, static: StaticInfo) -> list[PlannedRead]:
    """WorkOffset/G5x/<axis> per configured G code, one value per axis, at the counters period."""
    reads: list[PlannedRead] = []
    for g_code in poll.work_offsets if static.axis_names else ():
        specs = tuple(MetricSpec(f"WorkOffset/G{g_code}/{axis}", MetricType.DOUBLE, axis_unit(axis),
                                 description="work-coordinate offset (FOCAS library)")
                      for axis in static.axis_names)
        reads.append(PlannedRead(Group.COUNTERS, it.ReadWorkOffsets(it.work_offset_number(g_code)), specs))
    return reads


def axis_unit(axis_name: str) -> str:
    """Engineering unit of an axis position: degrees for rotary A/B/C, millimetres otherwise."""
    return "deg" if axis_name[:1].upper() in ROTARY_AXES else "mm"


def _macro_reads(poll: PollSettings) -> list[PlannedRead]:
    reads = []
    for macro in poll.macros:
        specs = tuple(MetricSpec(name, MetricType.DOUBLE, writable=True) for name in macro.names)
        reads.append(PlannedRead(Group.MACROS, it.ReadMacros(macro.first, macro.last), specs,
                                 (macro.deadband,) * len(specs)))
    return reads


def _pmc_reads(poll: PollSettings) -> list[PlannedRead]:
    reads = []
    for pmc in poll.pmc:
        target = pmc.target
        kind = MetricType.BOOLEAN if pmc.bits else PMC_METRIC_TYPES[target.data_type]
        specs = tuple(MetricSpec(name, kind, writable=True) for name in pmc.names)
        item = it.ReadPmc(target.area, target.start, target.end, target.data_type)
        reads.append(PlannedRead(Group.PMC, item, specs, (pmc.deadband,) * len(specs), bits=pmc.bits))
    return reads


def _numbered_reads(poll: PollSettings, static: StaticInfo) -> list[PlannedRead]:
    """Parameters and diagnoses; an all-axes one (`axis: all`, or an axis-0 number the control answered
    as axis-type) is one read publishing `<name>/<axis name>` per controlled axis."""
    reads = []
    kinds = (("Param", Group.PARAMS, it.ReadParams, poll.params, True),
             ("Diag", Group.DIAGS, it.ReadDiag, poll.diags, False))
    for folder, group, make, entries, writable in kinds:
        for entry in entries:
            name = entry.name
            axis = entry.axis
            if axis == 0 and (folder, entry.number) in static.per_axis:
                axis = ALL_AXES
            per_axis = axis == ALL_AXES
            names = [f"{name}/{axis_name}" for axis_name in static.axis_names] if per_axis else [name]
            specs = tuple(MetricSpec(n, MetricType.DOUBLE, writable=writable) for n in names)
            reads.append(PlannedRead(group, make(entry.number, entry.number, axis), specs,
                                     (entry.deadband,) * len(specs)))
    return reads


# ---- results to values -----------------------------------------------------------------------------


def metric_values(read: PlannedRead, result: object) -> list[tuple[MetricSpec, object]]:
    """The (metric, value) pairs one successful read result gives, for the metrics the read declares."""
    return list(zip(read.metrics, value_extractor(read)(result), strict=False))


ValueExtractor = Callable[[object], list[object]]
_SHARED_EXTRACTORS: dict[int, tuple[PlannedRead, ValueExtractor]] = {}  # id(read) -> (read, its extractor)


def shared_value_extractor(read: PlannedRead) -> ValueExtractor:
    """value_extractor, one per read object for the whole process: the reads of a plan are shared by every
    machine polling alike (MachinePlan.build), and an extractor depends on nothing else (it keeps no state)."""
    found = _SHARED_EXTRACTORS.get(id(read))
    if found is not None and found[0] is read:
        return found[1]
    if len(_SHARED_EXTRACTORS) >= SHARED_READS_LIMIT * 64:
        _SHARED_EXTRACTORS.clear()
    extractor = value_extractor(read)
    _SHARED_EXTRACTORS[id(read)] = (read, extractor)
    return extractor


def value_extractor(read: PlannedRead) -> ValueExtractor:
    """A function from the read's result to its metrics' values (in `read.metrics` order, each coerced to
    its metric's type). Built once per read and session: a poll tick calls it for every read that moved,
    so what depends only on the read (how to pick the values, which coercion) is decided here."""
    pick = _picker(read.item)
    coercers = [_COERCERS.get(spec.type, _unchanged) for spec in read.metrics]
    count = len(coercers)
    bits = read.bits
    if not bits and all(coerce is _to_float for coerce in coercers):  # positions, macros, feed, loads

        def floats(result: object) -> list[object]:
            values = pick(result)
            return [v if type(v) is float else _to_float(v) for v in values[:count]]

        return floats
    if not bits and all(coerce is _to_int for coerce in coercers):  # PMC ranges, integer parameters

        def ints(result: object) -> list[object]:
            values = pick(result)
            return [v if type(v) is int else _to_int(v) for v in values[:count]]

        return ints

    def extract(result: object) -> list[object]:
        values = pick(result)
        if bits:
            values = [bool(int(byte) >> bit & 1) for byte in values for bit in range(8)]  # type: ignore[call-overload]
        return [coerce(value) for coerce, value in zip(coercers, values, strict=False)]

    return extract


def elementwise(read: PlannedRead) -> bool:
    """Whether metric i of this read is element i of its list result, coerced on its own (macros, PMC
    ranges, positions, loads). Then an element equal to, and of the same type as, the element the read
    gave last tick yields the value already offered for that metric last tick, so a tick may skip it
    (edge.collect.poller). Mirrors value_extractor's `floats` and `ints` cases."""
    return element_coercion(read) is not None


def element_coercion(read: PlannedRead) -> tuple[type, Callable[[object], object]] | None:
    """For an elementwise read, what each element becomes: (the type it already has when no coercion is
    needed, the coercion otherwise), as value_extractor's `floats` and `ints` apply it. The tick coerces
    only the elements that moved, without extracting the whole list; None for any other read."""
    if read.bits or _picker(read.item) is not _as_list:
        return None
    coercers = {_COERCERS.get(spec.type, _unchanged) for spec in read.metrics}
    if coercers == {_to_float}:
        return float, _to_float
    if coercers == {_to_int}:
        return int, _to_int
    return None


def _picker(item: it.ReadItem) -> Callable[[Any], Sequence[object]]:
    """How a result of this item becomes its metrics' raw values, in order."""
    match item:
        case it.ReadStatus():
            return lambda result: [pick(result) for _, pick in STATUS_METRICS]
        case it.ReadSysInfo():
            return lambda result: [pick(result) for _, pick in SYSINFO_METRICS]
        case it.ReadProgramNumber():
            return lambda result: [result.running, result.main]
        case it.ReadExecProgramName():
            return lambda result: [result.name]
        case it.ReadTimer():
            return lambda result: [result.minutes * 60 + result.msec / 1000]
        case it.ReadActiveAlarms():
            return _alarm_values
        case it.ReadAxisNames() | it.ReadSpindleNames():
            return lambda result: [",".join(str(name) for name in result)]
        case it.ReadParams(axis=-1) | it.ReadDiag(axis=-1):  # one number, one value per axis slot
            return lambda result: list(result[0].values)
        case it.ReadParams() | it.ReadDiag():
            return lambda result: [record.value for record in result]
        case it.ReadOperatorMessages():
            return lambda result: [json.dumps([{"number": m.number, "type": m.type, "text": m.text} for m in result],
                                              separators=(",", ":"))]
        case (it.ReadMacros() | it.ReadPmc() | it.ReadSpindleLoad() | it.ReadPositions() | it.ReadServoMeter()
              | it.ReadToolOffsets() | it.ReadWorkOffsets()):
            return _as_list
        case it.ReadAlarmHistory():
            return lambda result: []  # published per entry as events, see edge.collect.alarms
        case it.ReadModalGCodes():
            return lambda result: [json.dumps({str(m.group): m.code for m in result}, separators=(",", ":"))]
        case _:
            return lambda result: [result]


def _as_list(result: Any) -> Sequence[object]:
    return result if type(result) is list else list(result)


def _alarm_values(result: Any) -> list[object]:
    alarms = list(result)
    return [active_alarms_json(alarms), len(alarms)]


def active_alarms_json(alarms: Sequence[ActiveAlarm]) -> str:
    return json.dumps([{"type": a.type, "number": a.number, "axis": a.axis, "message": a.message}
                       for a in alarms], separators=(",", ":"))


def _to_float(value: object) -> object:
    """A Double/Float metric: ints (and bools) become floats; None and anything else pass."""
    return float(value) if isinstance(value, int | float) else value


def _to_int(value: object) -> object:
    """An integer metric: a whole float (a REAL parameter holding a count) becomes an int."""
    return int(value) if isinstance(value, float) and value.is_integer() else value


def _unchanged(value: object) -> object:
    return value


_COERCERS: dict[MetricType, Callable[[object], object]] = {
    MetricType.DOUBLE: _to_float, MetricType.FLOAT: _to_float,
    **dict.fromkeys((MetricType.INT8, MetricType.INT16, MetricType.INT32, MetricType.INT64, MetricType.UINT8,
                     MetricType.UINT16, MetricType.UINT32, MetricType.UINT64), _to_int),
}


# ---- when groups are due ---------------------------------------------------------------------------


_GROUP_BITS = {group: 1 << index for index, group in enumerate(Group)}
# bit mask of due groups -> that set: the same for every schedule, so one dict for the process (one each
# was ~2 kB a machine)
_COMBINATIONS: dict[int, frozenset[Group]] = {}


def group_set(groups: Iterable[Group]) -> frozenset[Group]:
    """The process's one frozenset of these groups (what `Schedule.due` hands out): a poller keys its
    batches and read times by such sets, and a set of its own per machine was ~0.3 kB each."""
    mask = 0
    for group in groups:
        mask |= _GROUP_BITS[group]
    return _combination(mask)


def _combination(mask: int) -> frozenset[Group]:
    groups = _COMBINATIONS.get(mask)
    if groups is None:
        groups = _COMBINATIONS[mask] = frozenset(g for g, bit in _GROUP_BITS.items() if mask & bit)
    return groups


class Schedule:
    """Per-group due times for one session. Static is due once per connection; a group that fell
    behind is not caught up tick by tick: its next time moves past `now`, and the skipped periods
    are counted."""

    def __init__(self, periods: dict[Group, float]) -> None:
        self.periods = periods  # the plan's (shared by the plans of one poll setting): read, never changed
        self._next: dict[Group, float] = {}
        self._static_pending = True
        self.skipped = 0

    def start(self, now: float) -> None:
        """A new connection: static data and every group are due at once."""
        self._next = dict.fromkeys(self.periods, now)
        self._static_pending = True

    def due(self, now: float) -> frozenset[Group]:
        """The groups due at `now`; advances their next time. The same combination of groups is the same
        frozenset object every time (the poller keys its prepared batches by it)."""
        mask = _GROUP_BITS[Group.STATIC] if self._static_pending else 0
        self._static_pending = False
        for group, when in self._next.items():
            if when > now:
                continue
            mask |= _GROUP_BITS[group]
            period = self.periods[group]
            following = when + period
            if following <= now:
                missed = int((now - following) // period) + 1
                self.skipped += missed
                following += missed * period
            self._next[group] = following
        groups = _COMBINATIONS.get(mask)
        return groups if groups is not None else _combination(mask)

    def next_due(self) -> float | None:
        """The earliest time any group is due (None before start())."""
        return min(self._next.values()) if self._next else None
