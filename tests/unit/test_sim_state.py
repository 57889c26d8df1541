"""The simulated machine's model: cycle, counters, write rules and EW codes, alarm ring, clock."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path
from zoneinfo import ZoneInfo

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge import ConfigError
from edge.focas import functions as fn
from edge.focas.errors import (
    EW_ATTRIB,
    EW_DATA,
    EW_FUNC,
    EW_LENGTH,
    EW_NUMBER,
    EW_PASSWD,
    EW_PATH,
    AccessDenied,
    CncError,
    LengthError,
    OutOfRange,
)
from edge.focas.frame import RequestSubpacket
from edge.focas.model import ParamType, PmcType
from edge.sim.admin import AdminServer, HttpError
from edge.sim.faults import FaultPlan
from edge.sim.fleet import Fleet, MachineSpec
from edge.sim.native_server import answer_subpacket
from edge.sim.profiles import PROFILES, get_profile
from edge.sim.scenario import load_scenario, parse_scenario
from edge.sim.state import ALARM_HISTORY_SIZE, CycleSpec, MachineState, clock_macro_error, clock_macro_value

T0 = 1_750_000_000.0  # 2025-06-15 15:06:40 UTC


class FakeClock:
    def __init__(self, start: float = T0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def tick(self, seconds: float) -> None:
        self.now += seconds


def machine(profile: str = "30i", **kwargs: object) -> tuple[MachineState, FakeClock]:
    clock = FakeClock()
    cycle = kwargs.pop("cycle", CycleSpec(cut_seconds=10.0, idle_seconds=5.0))
    state = MachineState(profile, time_source=clock, cycle=cycle, **kwargs)  # type: ignore[arg-type]
    return state, clock


# ---- cycle ---------------------------------------------------------------------------------------------


def test_cycle_runs_stops_and_repeats() -> None:
    state, clock = machine()
    clock.tick(3.0)  # cutting
    cutting = state.status()
    assert (cutting.aut, cutting.run, cutting.motion) == (1, 3, 1)
    assert state.actual_feed() > 0 and state.spindle_speed() > 0
    first = state.positions("absolute")
    clock.tick(0.5)
    assert state.positions("absolute") != first
    clock.tick(8.0)  # 11.5 s: between parts
    idle = state.status()
    assert (idle.run, idle.motion) == (0, 0)
    assert state.actual_feed() == 0.0 and state.spindle_speed() == 0.0
    assert state.sequence_number() == 0
    clock.tick(5.0)  # 16.5 s: the next part is being cut
    assert state.status().run == 3


def test_part_count_increments_once_per_cycle() -> None:
    state, clock = machine(start_parts=7)
    total = state.read_param_value(6712)
    clock.tick(9.9)
    assert state.part_count == 7
    clock.tick(0.2)  # 10.1 s: first part done
    assert state.part_count == 8
    clock.tick(15.0 * 4)  # four more cycles
    assert state.part_count == 12
    assert state.read_param_value(6712) == total + 5
    (record,) = state.read_params(6711, 6711)
    assert (record.number, record.axis, record.type, record.value) == (6711, 0, ParamType.TWO_WORD, 12)


def test_a_long_jump_counts_every_part_and_keeps_the_ring_bounded() -> None:
    state, clock = machine(cycle=CycleSpec(cut_seconds=10.0, idle_seconds=5.0, alarm_every=1))
    clock.tick(15.0 * 100_000)
    assert state.part_count == 100_000
    assert len(state.alarm_history()) == ALARM_HISTORY_SIZE


def test_different_seeds_do_not_run_in_step() -> None:
    a, clock_a = machine(seed=0)
    b, clock_b = machine(seed=3)
    clock_a.tick(2.0)
    clock_b.tick(2.0)
    assert a.positions() != b.positions()


# ---- macros --------------------------------------------------------------------------------------------


def test_macros_read_write_and_log() -> None:
    state, clock = machine()
    assert state.read_macros(500, 502) == [12.5, 0.0, 3.0]
    assert state.read_macro(150) is None  # vacant
    clock.tick(1.0)
    state.write_macro(150, 1.25)
    state.write_macro(500, None, protocol="packed")
    assert state.read_macros(150, 150) == [1.25]
    assert state.read_macro(500) is None
    log = state.writes("macro:")
    assert [(w.time, w.protocol, w.target, w.old, w.new) for w in log] == [
        (T0 + 1.0, "native", "macro:150", None, 1.25),
        (T0 + 1.0, "packed", "macro:500", 12.5, None),
    ]


@pytest.mark.parametrize(("first", "last"), [(1, 1), (99, 100), (200, 200), (199, 500), (1000, 1000), (5, 4)])
def test_macro_numbers_outside_the_ranges_are_ew_number(first: int, last: int) -> None:
    state, _ = machine()
    with pytest.raises(OutOfRange) as caught:
        state.read_macros(first, last)
    assert caught.value.code == EW_NUMBER
    if first == last:
        with pytest.raises(OutOfRange):
            state.write_macro(first, 1.0)
    assert state.write_log == []


# ---- PMC -----------------------------------------------------------------------------------------------


def test_pmc_areas_have_realistic_sizes() -> None:
    state, _ = machine("30i")
    assert set("GFYXARTKCDE") <= set(state.profile.pmc_sizes)
    assert state.pmc_size("R") == 8000 and state.pmc_size("D") == 10000 and state.pmc_size("X") == 128
    assert machine("16i")[0].pmc_size("E") == 8000


def test_pmc_write_rules() -> None:
    state, _ = machine()
    state.write_pmc("R", 200, bytes(range(32)))
    assert state.read_pmc_bytes("R", 200, 231) == bytes(range(32))
    with pytest.raises(LengthError) as caught:
        state.write_pmc("R", 200, bytes(33))
    assert caught.value.code == EW_LENGTH
    with pytest.raises(OutOfRange) as outside:
        state.write_pmc("R", 7999, b"\x01\x02")  # runs past R7999
    assert outside.value.code == EW_NUMBER
    with pytest.raises(OutOfRange) as area:
        state.write_pmc("M", 0, b"\x01")
    assert area.value.code == EW_ATTRIB
    assert [(w.target, w.old, w.new) for w in state.writes("pmc:")] == [
        ("pmc:R200-R231", bytes(32), bytes(range(32)))]


def test_pmc_typed_reads() -> None:
    state, _ = machine()
    state.write_pmc("D", 100, b"\xff\xfe\x00\x00\x01\x00\x3f\x80\x00\x00")
    assert state.read_pmc("D", 100, 101, PmcType.WORD) == [-2]
    assert state.read_pmc("D", 102, 105, PmcType.LONG) == [256]
    assert state.read_pmc("D", 106, 109, PmcType.FLOAT) == [1.0]
    assert state.read_pmc("D", 100, 101, PmcType.BYTE) == [255, 254]
    assert state.read_pmc("D", 2204, 2205, PmcType.WORD) == [600]
    with pytest.raises(LengthError):
        state.read_pmc("D", 100, 100, PmcType.WORD)
    with pytest.raises(OutOfRange) as no_float:
        machine("16i")[0].read_pmc("D", 0, 3, PmcType.FLOAT)
    assert no_float.value.code == EW_ATTRIB


def test_pmc_signals_follow_the_machine() -> None:
    state, clock = machine()
    clock.tick(3.0)
    assert state.read_pmc_bytes("F", 0, 0)[0] & 0b0010_0000  # STL while cutting
    clock.tick(9.0)
    assert not state.read_pmc_bytes("F", 0, 0)[0] & 0b0010_0000


# ---- parameters and diagnoses -----------------------------------------------------------------------------


def test_parameter_write_needs_the_enable_switch() -> None:
    state, _ = machine()
    with pytest.raises(AccessDenied) as caught:
        state.write_param(6711, 0, 5)
    assert caught.value.code == EW_PASSWD
    state.set_param_write_enable(True)
    state.write_param(6711, 0, 5)
    state.write_param(1815, 2, 0b0011_0001)
    assert state.part_count == 5
    assert state.read_params(1815, 1815, 2)[0].values == (0b0011_0001,)
    assert [(w.target, w.old, w.new) for w in state.writes("param:")] == [
        ("param:6711", 0, 5), ("param:1815/2", 0b0011_0000, 0b0011_0001)]


@pytest.mark.parametrize(("number", "axis", "value", "code"), [
    (9999, 0, 1, EW_NUMBER),
    (1815, 0, 1, EW_ATTRIB),  # per-axis needs an axis
    (1815, 9, 1, EW_ATTRIB),
    (6711, 1, 1, EW_ATTRIB),  # not per axis
    (1815, 1, 256, EW_DATA),  # a bit parameter holds one byte
    (1825, 1, 40000, EW_DATA),  # word
    (6711, 0, 1.5, EW_DATA),  # 2-word is an integer
])
def test_parameter_write_errors(number: int, axis: int, value: float, code: int) -> None:
    state, _ = machine()
    state.set_param_write_enable(True)
    with pytest.raises(CncError) as caught:
        state.write_param(number, axis, value)
    assert caught.value.code == code
    assert state.write_log == []


def test_every_parameter_type_is_present() -> None:
    for name in ("16i", "30i"):
        state, _ = machine(name)
        types = {r.type for r in state.read_params(0, 9999, -1)}
        expected = {0, 1, 2, 3, 4} if state.profile.wide_records else {0, 1, 2, 3}
        assert types == expected, name


def test_parameter_record_axis_forms() -> None:
    state, _ = machine("16i")
    (all_axes,) = state.read_params(1020, 1020, -1)
    assert all_axes.axis == -1 and all_axes.values == tuple(ord(a) for a in "XYZB")
    (one,) = state.read_params(1020, 1020, 3)
    assert (one.axis, one.values) == (3, (ord("Z"),))
    (whole,) = state.read_params(3281, 3281, 2)
    assert (whole.axis, whole.values) == (0, (0,))
    with pytest.raises(OutOfRange):
        state.read_params(1020, 1020, 5)
    with pytest.raises(OutOfRange) as none:
        state.read_params(2, 19)
    assert none.value.code == EW_NUMBER


def test_diagnoses_follow_the_cycle() -> None:
    state, clock = machine()
    clock.tick(2.3)
    records = {r.number: r for r in state.read_diag(980, 982, -1)}
    machine_pos = state.positions("machine")
    assert list(records[980].values) == [int(v * 1000) for v in machine_pos]
    clock.tick(10.0)
    (load,) = state.read_diag(410, 410)
    assert load.value == 0


# ---- alarms --------------------------------------------------------------------------------------------


def test_alarms_come_and_go_and_enter_the_history() -> None:
    cycle = CycleSpec(cut_seconds=10.0, idle_seconds=5.0, alarm_every=2, alarm_seconds=3.0)
    state, clock = machine(cycle=cycle, timezone="America/Chicago", clock_offset=90.0)
    seeded = len(state.alarm_history())
    clock.tick(15.0 + 10.6)  # second cycle's idle: alarm raised at 25.5 s
    alarms = state.active_alarms()
    assert len(alarms) == 1 and state.status().alarm == 1
    assert state.alarm_status() == 1 << alarms[0].type
    newest = state.alarm_events(1)[0]
    raised_at = T0 + 25.5
    expected_local = datetime.fromtimestamp(raised_at + 90.0, ZoneInfo("America/Chicago")).replace(
        tzinfo=None, microsecond=0)
    assert newest.local_time == expected_local
    assert newest.utc_time == datetime.fromtimestamp(raised_at, UTC)
    entry = state.alarm_history(1)[0]
    assert (entry.alm_no, entry.occurred) == (alarms[0].number, expected_local.replace(tzinfo=UTC))
    clock.tick(3.0)
    assert state.active_alarms() == [] and state.status().alarm == 0
    assert len(state.alarm_history()) == seeded + 1


def test_history_is_newest_first_and_depth_is_clamped() -> None:
    state, clock = machine()
    state.raise_alarm(1004, message="COOLANT LEVEL LOW")
    clock.tick(60)
    state.raise_alarm(2001, type=4, axis=2, message="LUBE")
    history = state.alarm_history(2)
    assert [e.alm_no for e in history] == [2001, 1004]
    assert history[0].occurred - history[1].occurred == timedelta(seconds=60)
    assert len(state.alarm_history(0)) == 1
    assert len(state.alarm_history(10_000)) == len(state.alarm_history(ALARM_HISTORY_SIZE))
    assert {a.number for a in state.active_alarms()} == {1004, 2001}
    state.clear_alarms(1004)
    assert [a.number for a in state.active_alarms()] == [2001]
    state.clear_alarms()
    assert state.active_alarms() == [] and state.alarm_status() == 0


def test_history_ring_keeps_250() -> None:
    state, clock = machine()
    for number in range(300):
        clock.tick(1)
        state.raise_alarm(3000 + number)
    history = state.alarm_history(ALARM_HISTORY_SIZE)
    assert len(history) == ALARM_HISTORY_SIZE
    assert history[0].alm_no == 3299 and history[-1].alm_no == 3050


# ---- clock ---------------------------------------------------------------------------------------------


def test_clock_is_real_time_plus_offset_in_the_cnc_zone() -> None:
    state, _ = machine(timezone="Europe/Berlin", clock_offset=-30.0)
    assert state.clock() == datetime(2025, 6, 15, 17, 6, 10)  # UTC+2 in June, 30 s slow
    assert state.clock_utc() == datetime(2025, 6, 15, 15, 6, 10, tzinfo=UTC)
    state.timezone = "Asia/Tokyo"
    state.clock_offset = 0
    assert state.clock() == datetime(2025, 6, 16, 0, 6, 40)


def test_setting_the_clock_moves_the_offset() -> None:
    state, clock = machine(timezone="Europe/Berlin")
    state.set_clock(datetime(2025, 6, 15, 17, 10, 0))
    assert state.clock_offset == pytest.approx(200.0)
    clock.tick(5)
    assert state.clock() == datetime(2025, 6, 15, 17, 10, 5)
    state.set_time_of_day(8, 0, 0)
    assert state.clock() == datetime(2025, 6, 15, 8, 0, 0)
    with pytest.raises(CncError) as bad:
        state.set_time_of_day(25, 0, 0)
    assert bad.value.code == EW_DATA


def test_the_clock_macro_reads_as_the_cnc_clock_when_it_answers() -> None:
    """The hook the timestamp tests and the fleet benchmark compare stamps with (seconds mod 1000, ms)."""
    state, clock = machine(clock_offset=7.25)
    state.write_macro(500, 1.0)
    state.write_macro(501, 3.0)
    state.write_macro(502, None)
    assert state.read_macros(500, 502)[0] == 1.0  # no hook: an ordinary macro
    state.clock_macro = 500
    clock.tick(0.4567)
    value = state.read_macros(500, 502)[0]
    assert value == clock_macro_value(T0 + 0.4567 + 7.25) == round((T0 + 7.7067) % 1000, 3)
    assert state.read_macros(501, 502) == [3.0, None]  # the others are what they hold
    assert clock_macro_error(T0 + 7.7067 + 0.012, value) == pytest.approx(0.012, abs=1e-3)
    assert clock_macro_error(T0 + 7.7067 - 0.012, value) == pytest.approx(-0.012, abs=1e-3)
    assert clock_macro_error(999.995, 0.005) == pytest.approx(-0.01)  # across the wrap of the modulo


def test_timers() -> None:
    state, clock = machine()
    before = state.timer(0)
    clock.tick(120)
    after = state.timer(0)
    assert after.minutes - before.minutes == 2
    assert state.timer(2).minutes >= 0 and 0 <= state.timer(3).msec < 60_000
    with pytest.raises(OutOfRange):
        state.timer(9)


# ---- profiles and the server's dispatch (pure) ------------------------------------------------------------


def test_profiles() -> None:
    assert set(PROFILES) >= {"0i-F", "16i", "30i", "31i"}
    assert get_profile("16i").sysinfo.max_axis == 8 and get_profile("31i").sysinfo.max_axis == 32
    assert get_profile("16I") is PROFILES["16i"] and get_profile("31i-B") is PROFILES["31i"]
    assert {p.response_version for p in PROFILES.values()} == {2, 3, 4}
    with pytest.raises(ValueError, match="expected one of"):
        get_profile("18i")


@pytest.mark.parametrize("name", ["16i", "30i", "0i-F"])
def test_only_the_profiles_record_form_answers(name: str) -> None:
    state, _ = machine(name)
    wide = state.profile.wide_records
    for function in (fn.READ_PARAMS_4, fn.READ_PARAMS_8, fn.READ_DIAG_4, fn.READ_DIAG_8):
        first = 6711 if "params" in function.name else 980
        answer = answer_subpacket(state, function.request(first, first, 0))
        answers_here = (function.command in (0x8D, 0x93)) == wide
        assert answer.rc == (0 if answers_here else EW_FUNC), (name, hex(function.command))


def test_unknown_command_path_and_forced_codes() -> None:
    state, _ = machine()
    assert answer_subpacket(state, RequestSubpacket(1, 0x7777)).rc == EW_FUNC
    assert answer_subpacket(state, fn.STATINFO.request(path=2)).rc == EW_PATH
    faults = FaultPlan(ew={"statinfo": 15, 0x18: 6})
    assert answer_subpacket(state, fn.STATINFO.request(), faults).rc == 15
    assert answer_subpacket(state, fn.SYSINFO.request(), faults).rc == 6
    assert answer_subpacket(state, fn.READ_MACROS.request(500, 500), faults).rc == 0


def test_pmc_write_over_32_bytes_is_ew_length_on_the_wire() -> None:
    state, _ = machine()
    answer = answer_subpacket(state, fn.write_pmc_request("R", 0, bytes(33)))
    assert answer.rc == EW_LENGTH
    assert answer_subpacket(state, fn.write_pmc_request("R", 0, bytes(32))).rc == 0


@given(st.integers(-(2**31), 2**31 - 1), st.integers(-(2**31), 2**31 - 1), st.integers(-(2**15), 2**15 - 1),
       st.integers(0, 0xFFFF))
def test_property_any_request_gets_an_answer(first: int, last: int, axis: int, command: int) -> None:
    state = MachineState("30i", time_source=lambda: T0)
    answer = answer_subpacket(state, RequestSubpacket(1, command, (first, last, axis, 0, 0)))
    assert (answer.cls, answer.path, answer.command) == (1, 1, command)
    assert answer.rc >= 0 and (answer.rc == 0 or answer.payload == b"")


# ---- faults, scenario, admin (in-process) ----------------------------------------------------------


def test_counted_faults_clear_themselves() -> None:
    plan = FaultPlan(hang=2, drop_after=2, refuse=-1)
    assert [plan.take_hang() for _ in range(3)] == [True, True, False]
    assert [plan.take_drop() for _ in range(3)] == [False, True, False]
    assert all(plan.take_refuse() for _ in range(5))
    plan.update({"ew": {"0x15": 6, "read_pmc": 18}})
    assert plan.ew_for(0x15, "read_macros") == 6 and plan.ew_for(0x8001, "read_pmc") == 18
    plan.clear()
    assert plan.describe()["refuse"] == 0 and plan.ew_for(0x15, "read_macros") is None
    with pytest.raises(ValueError, match="unknown fault"):
        plan.update({"explode": 1})


def test_scenario_file(tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(
        "base_port: 0\nadmin_port: 0\nmachines:\n"
        "  - {name: mill, profile: 30i, timezone: Europe/Berlin, clock_offset: 12.5,"
        " cycle: {cut_seconds: 3, idle_seconds: 2, alarm_every: 1}, macros: {500: 2.5},"
        " faults: {latency: 0.1}}\n"
        "  - {name: lathe, profile: 16i, count: 2}\n")
    scenario = load_scenario(path)
    assert [m.name for m in scenario.machines] == ["mill", "lathe-1", "lathe-2"]
    mill = scenario.machines[0]
    assert (mill.timezone, mill.clock_offset, mill.cycle.alarm_every, mill.macros) == (
        "Europe/Berlin", 12.5, 1, {500: 2.5})
    fleet = Fleet(scenario.machines, base_port=0)
    assert fleet[0].state.read_macro(500) == 2.5 and fleet[0].faults.latency == 0.1
    assert fleet[1].state.profile.name == "16i"


def test_bad_scenario_lists_every_problem() -> None:
    with pytest.raises(ConfigError) as caught:
        parse_scenario({"machines": [{"profile": "18i", "timezone": "Mars/Base", "faults": {"boom": 1}},
                                     {"cycle": {"cut_seconds": -1}}], "base_port": 70000})
    text = "\n".join(caught.value.problems)
    for fragment in ("machines.0.profile", "machines.0.timezone", "machines.0.faults",
                     "machines.1.cycle.cut_seconds", "base_port"):
        assert fragment in text
    with pytest.raises(ConfigError):
        parse_scenario({"machines": []})


def test_admin_routes_in_process() -> None:
    fleet = Fleet([MachineSpec(profile="30i"), MachineSpec(profile="16i")], base_port=0)
    admin = AdminServer(fleet)
    listing = admin.handle("GET", "/machines", {})
    assert [m["profile"] for m in listing] == ["30i", "16i"]
    admin.handle("POST", "/machines/1/state", {"macros": {"501": 4.5}, "param_write_enable": True,
                                               "params": {"1815/2": 1}, "pmc": {"R10": [7, 8]},
                                               "raise_alarm": {"number": 1004, "type": "EX"}})
    state = fleet[1].state
    assert state.read_macro(501) == 4.5 and state.param_write_enabled
    assert state.read_param_value(1815, 2) == 1 and state.read_pmc_bytes("R", 10, 11) == b"\x07\x08"
    assert [a.number for a in state.active_alarms()] == [1004]
    result = admin.handle("POST", "/machines/0/faults", {"hang": 1, "ew": {"read_macros": 6}})
    assert result["faults"]["hang"] == 1 and fleet[0].faults.ew_for(0x15, "read_macros") == 6
    writes = admin.handle("GET", "/machines/1/writes", {})
    assert writes[0]["target"] == "macro:501" and writes[0]["protocol"] == "admin"
    with pytest.raises(HttpError) as missing:
        admin.handle("GET", "/machines/5", {})
    assert missing.value.status == 404
    with pytest.raises(ValueError):
        admin.handle("POST", "/machines/0/state", {"colour": "red"})


def test_fleet_machines_raise_and_clear_alarms_by_default() -> None:
    clock = FakeClock()
    fleet = Fleet([MachineSpec(profile="0i-F", seed=0)], base_port=0, time_source=clock)
    state = fleet[0].state
    seen: set[int] = set()
    for _ in range(3 * 16 * 4):  # three 16-second cycles in quarter seconds
        clock.tick(0.25)
        seen.update(a.number for a in state.active_alarms())
    assert seen, "no alarm came during three cycles"
    clock.tick(8.0)
    assert state.active_alarms() == []


def test_hang_on_aims_at_one_function_and_counts_down() -> None:
    from edge.sim.faults import FaultPlan

    faults = FaultPlan()
    faults.update({"hang_on": {"write_macros": 1, "0x8002": -1}})
    assert not faults.take_hang_on([(0x15, "read_macros"), (0x45, "read_clock")])  # polls never hang
    assert faults.take_hang_on([(0x16, "write_macros")])
    assert not faults.take_hang_on([(0x16, "write_macros")])  # once
    assert faults.take_hang_on([(0x8002, "write_pmc")]) and faults.take_hang_on([(0x8002, "write_pmc")])
    assert faults.describe()["hang_on"] == {"write_macros": 0, str(0x8002): -1}
