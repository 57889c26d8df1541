from __future__ import annotations

import json

import pytest

from edge.collect.plan import (
    Group,
    MachinePlan,
    PlannedRead,
    Schedule,
    StaticInfo,
    axis_unit,
    metric_values,
    shared_value_extractor,
    value_extractor,
)
from edge.config import parse_config
from edge.focas import items as it
from edge.focas.model import ActiveAlarm, ParamRecord, PmcType, ProgramNumbers, StatInfo, SysInfo
from edge.samples import MetricSpec, MetricType
from edge.service.settings import poll_settings

CONFIG = """
mqtt: {host: b, formats: [json]}
alarms: {mode: ActivePlusHistory, history_interval: 5m, history_depth: 50}
machines:
  - id: m1
    host: h
    poll:
      periods: {status: 250ms, macros: 1s, pmc: 2s, params: 60s, diags: 30s}
      positions: [absolute, distance]
      macros: ["500-502", {first: 600, name: Tool/Offset, deadband: 0.1}]
      pmc: [{area: D, range: D2204-D2207, data_type: word}]
      params: [{number: 1815, axis: 1}]
      diags: [980]
"""
STATIC = StaticInfo(axis_names=("X", "Y", "B"), spindle_names=("S1", "S2"))


@pytest.fixture
def plan() -> MachinePlan:
    config = parse_config(CONFIG, "t", {})
    return MachinePlan.build(poll_settings(config.machines[0].poll, config.alarms), STATIC)


def names(reads: list[PlannedRead]) -> list[str]:
    return [spec.name for read in reads for spec in read.metrics]


def test_groups_hold_the_configured_reads(plan: MachinePlan) -> None:
    macros = plan.reads_for([Group.MACROS])
    assert [r.item for r in macros] == [it.ReadMacros(500, 502), it.ReadMacros(600, 600)]
    assert names(macros) == ["Macro/500", "Macro/501", "Macro/502", "Tool/Offset"]
    (pmc,) = plan.reads_for([Group.PMC])
    assert pmc.item == it.ReadPmc("D", 2204, 2207, PmcType.WORD)
    assert names([pmc]) == ["PMC/D2204", "PMC/D2206"] and pmc.metrics[0].type is MetricType.INT16
    assert [r.item for r in plan.reads_for([Group.PARAMS, Group.DIAGS])] == [
        it.ReadParams(1815, 1815, 1), it.ReadDiag(980, 980, 0)]
    assert [r.item for r in plan.reads_for([Group.ALARM_HISTORY])] == [it.ReadAlarmHistory(50)]
    assert {r.item.operation for r in plan.reads_for([Group.STATIC])} == {
        "ReadSysInfo", "ReadAxisNames", "ReadSpindleNames"}


def test_status_metric_names_and_units(plan: MachinePlan) -> None:
    status = names(plan.reads_for([Group.STATUS]))
    for name in ("Status/Run", "Status/Mode", "Program/Number", "Spindle/1/Speed", "Spindle/2/Load",
                 "Axis/X/Absolute", "Axis/B/DistanceToGo", "Counters/Parts", "Feed/Actual"):
        assert name in status
    specs = {s.name: s for s in plan.metrics()}
    assert specs["Axis/X/Absolute"].unit == "mm" and specs["Axis/B/Absolute"].unit == "deg"
    assert specs["Spindle/1/Speed"].unit == "rpm"
    assert specs["Macro/500"].writable and not specs["Status/Run"].writable
    for name in ("Alarm/Active", "Alarm/Event", "Alarm/History", "Clock/Skew", "Device/Model"):
        assert name in specs
    assert "Device/AxisNames" not in specs
    lowered = [n.lower() for n in specs]
    assert len(lowered) == len(set(lowered))
    assert axis_unit("a1") == "deg"


def test_deadbands(plan: MachinePlan) -> None:
    assert plan.deadbands() == {"Tool/Offset": 0.1}


def test_history_read_only_in_history_mode() -> None:
    config = parse_config(CONFIG.replace("mode: ActivePlusHistory", "mode: ActiveOnly"), "t", {})
    plan = MachinePlan.build(poll_settings(config.machines[0].poll, config.alarms))
    assert plan.reads_for([Group.ALARM_HISTORY]) == []
    assert "Alarm/History" not in {s.name for s in plan.metrics()}


def test_without_drops_an_unsupported_function(plan: MachinePlan) -> None:
    smaller = plan.without("ReadSequenceNumber")
    assert "Program/Sequence" not in names(list(smaller.reads))
    assert len(smaller.reads) == len(plan.reads) - 1


def test_metric_values_for_each_kind(plan: MachinePlan) -> None:
    by_item = {type(r.item).__name__ + str(getattr(r.item, "first", "")): r for r in plan.reads}
    status = by_item["ReadStatus"]
    values = dict((s.name, v) for s, v in metric_values(status, StatInfo(1, 3, 1, 0, 1, 0, 0)))
    assert values["Status/Mode"] == "MEM" and values["Status/Run"] == "START"
    assert values["Status/Motion"] == "MTN" and values["Status/Emergency"] is True
    program = by_item["ReadProgramNumber"]
    assert [v for _, v in metric_values(program, ProgramNumbers(12, 34))] == [12, 34]
    macros = by_item["ReadMacros500"]
    assert [v for _, v in metric_values(macros, [1.5, None, 3])] == [1.5, None, 3.0]
    param = by_item["ReadParams1815"]
    assert metric_values(param, [ParamRecord(1815, 1, 0, (48,))])[0][1] == 48.0
    alarms = next(r for r in plan.reads if r.group is Group.ACTIVE_ALARMS)
    active, count = metric_values(alarms, [ActiveAlarm(1001, 2, 1, "OT")])
    assert json.loads(str(active[1])) == [{"type": 2, "number": 1001, "axis": 1, "message": "OT"}]
    assert count[1] == 1
    sysinfo = by_item["ReadSysInfo"]
    info = SysInfo(addinfo=0x0202, max_axis=32, cnc_type="30", mt_type=" M", series="G004",
                   version="21.0", axes="05")
    assert dict((s.name, v) for s, v in metric_values(sysinfo, info))["Device/Model"] == "30i-BM"
    unknown_mode = dict((s.name, v) for s, v in metric_values(status, StatInfo(42, 0, 0, 0, 0, 8, 0)))
    assert unknown_mode["Status/Mode"] == "42" and unknown_mode["Status/Alarm"] == "PMC"


def test_schedule_due_groups() -> None:
    schedule = Schedule({Group.STATUS: 0.25, Group.MACROS: 1.0, Group.PARAMS: 60.0})
    assert schedule.next_due() is None
    schedule.start(100.0)
    assert schedule.due(100.0) == {Group.STATIC, Group.STATUS, Group.MACROS, Group.PARAMS}
    assert schedule.due(100.1) == set()
    assert schedule.due(100.25) == {Group.STATUS}
    status_only = schedule.due(100.5)
    assert status_only == {Group.STATUS}
    assert schedule.due(100.75) is status_only  # one frozenset per combination: the poller keys on it
    assert schedule.due(101.0) == {Group.STATUS, Group.MACROS}
    assert schedule.next_due() == pytest.approx(101.25)
    assert schedule.skipped == 0


def test_schedule_overrun_skips_instead_of_piling_up() -> None:
    schedule = Schedule({Group.STATUS: 0.25})
    schedule.start(0.0)
    schedule.due(0.0)
    assert schedule.due(1.1) == {Group.STATUS}  # one tick, not four in a row
    assert schedule.skipped == 3  # 0.25 .. 1.0 overdue; 0.5, 0.75, 1.0 were skipped
    assert schedule.next_due() == pytest.approx(1.25)
    assert schedule.due(1.2) == set()


def test_static_is_due_once_per_connection() -> None:
    schedule = Schedule({Group.STATUS: 1.0})
    schedule.start(0.0)
    assert Group.STATIC in schedule.due(0.0)
    assert Group.STATIC not in schedule.due(1.0)
    schedule.start(5.0)  # reconnected
    assert Group.STATIC in schedule.due(5.0)


def test_pmc_bit_range_publishes_one_boolean_per_bit() -> None:
    from edge.collect.plan import Group, MachinePlan, metric_values
    from edge.config import AlarmsConfig, MachineConfig
    from edge.samples import MetricType

    machine = MachineConfig.model_validate(
        {"id": "m", "host": "h", "poll": {"pmc": [{"range": "R100-R101", "data_type": "bit"}]}})
    plan = MachinePlan.build(poll_settings(machine.poll, AlarmsConfig()))
    (read,) = plan.reads_for({Group.PMC})
    assert [m.name for m in read.metrics] == [f"PMC/R{a}.{b}" for a in (100, 101) for b in range(8)]
    assert {m.type for m in read.metrics} == {MetricType.BOOLEAN} and all(m.writable for m in read.metrics)
    values = [v for _, v in metric_values(read, [0b0000_1001, 0b1000_0000])]
    assert values == [True, False, False, True, False, False, False, False] + [False] * 7 + [True]


def _read(item: it.ReadItem, *types: MetricType, bits: bool = False) -> PlannedRead:
    return PlannedRead(Group.MACROS, item, tuple(MetricSpec(f"m{i}", t) for i, t in enumerate(types)),
                       bits=bits)


def test_extractors_coerce_each_value_to_its_metric_type() -> None:
    doubles = value_extractor(_read(it.ReadMacros(1, 4), *[MetricType.DOUBLE] * 3))
    assert doubles([1, 2.5, None, 9.0]) == [1.0, 2.5, None]  # an int becomes a float, one value too many
    assert [type(v) for v in doubles([1, 2.5, None])] == [float, float, type(None)]
    ints = value_extractor(_read(it.ReadPmc("R", 0, 2, PmcType.BYTE), *[MetricType.UINT8] * 3))
    assert ints([3, 4.0, 4.5]) == [3, 4, 4.5] and type(ints([3, 4.0, 4.5])[1]) is int
    mixed = value_extractor(_read(it.ReadMacros(1, 2), MetricType.DOUBLE, MetricType.STRING))
    assert mixed([7, 7]) == [7.0, 7]
    bits = value_extractor(_read(it.ReadPmc("R", 0, 0, PmcType.BYTE), *[MetricType.BOOLEAN] * 8, bits=True))
    assert bits([0b10000101]) == [True, False, True, False, False, False, False, True]
    params = value_extractor(_read(it.ReadParams(6711, 6711), MetricType.INT32))
    assert params([ParamRecord(6711, 0, 2, (12.0,))]) == [12]


def test_machines_polling_alike_share_reads_and_extractors_but_each_session_gets_its_own_plan() -> None:
    config = parse_config(CONFIG, "t", {})
    first = poll_settings(config.machines[0].poll, config.alarms)
    second = poll_settings(parse_config(CONFIG, "t", {}).machines[0].poll, config.alarms)  # equal, not the same
    a, b = MachinePlan.build(first, STATIC), MachinePlan.build(second, STATIC)
    assert a is not b, "the poller tells sessions apart by the plan's identity"
    assert a.reads is b.reads and a.metrics()[0] is b.metrics()[0]
    assert MachinePlan.build(first, StaticInfo(axis_names=("X",))).reads is not a.reads, "other axes, other reads"
    read = a.reads_for([Group.MACROS])[0]
    assert shared_value_extractor(read) is shared_value_extractor(b.reads_for([Group.MACROS])[0])
    assert shared_value_extractor(read)([1.0, 2.0, 3.0]) == value_extractor(read)([1.0, 2.0, 3.0])


def test_machines_polling_alike_share_their_tick_batches() -> None:
    from edge.collect.tick_batch import TickBatch

    config = parse_config(CONFIG, "t", {})
    a = MachinePlan.build(poll_settings(config.machines[0].poll, config.alarms), STATIC)
    b = MachinePlan.build(poll_settings(parse_config(CONFIG, "t", {}).machines[0].poll, config.alarms), STATIC)
    reads_a, reads_b = a.reads_for([Group.MACROS, Group.STATUS]), b.reads_for([Group.MACROS, Group.STATUS])
    positions = [a.reads.index(read) for read in reads_a]
    shared = TickBatch.shared(reads_a, positions)
    assert TickBatch.shared(reads_b, positions) is shared  # one batch, its request items one tuple
    built = TickBatch.build(reads_a, shared_value_extractor, positions)
    assert (shared.items, shared.extractors, shared.positions) == (built.items, built.extractors, built.positions)
    assert TickBatch.shared(reads_a, [p + 1 for p in positions]) is not shared, "other positions, another batch"
