"""The simulator's fast answer path (AnswerPlans) gives exactly the reference's bytes (answer_subpacket).

Two identical machines on one fake clock: one answers through NativeServer.answer_body (compiled plans),
the other through answer_subpacket + encode_response, request by request. Writes change both the same
way, so their write logs must stay equal too.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator
from datetime import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.focas import functions as fn
from edge.focas.errors import EW_FUNC, EW_NUMBER, EW_PATH, ProtocolError
from edge.focas.frame import (
    CLASS_CNC,
    CLASS_PMC,
    RequestSubpacket,
    decode_frame,
    decode_request_body,
    decode_response_body,
    encode_request_body,
    encode_response,
)
from edge.focas.function_entry import Context
from edge.focas.model import PmcType
from edge.focas.values import SlotForm, encode_scaled
from edge.sim import native_plans as ns  # the fast path's caches live in native_plans
from edge.sim.faults import FaultPlan
from edge.sim.native_handlers import HANDLERS, answer_subpacket
from edge.sim.native_plans import scaled_bytes
from edge.sim.native_server import NativeServer
from edge.sim.profiles import PROFILES, get_profile
from edge.sim.state import MachineState
from edge.sim.state_program import CycleSpec

T0 = 1_750_000_000.0
CYCLE = CycleSpec(cut_seconds=10.0, idle_seconds=5.0, alarm_every=2, alarm_seconds=3.0)
# Moments (s after T0) in different phases: cutting, tool change, dwell, between parts, alarm on, later.
MOMENTS = (0.0, 0.4, 3.3, 5.7, 11.2, 26.0, 41.3, 10_000.25)


class FakeClock:
    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> float:
        return self.now


class Twins:
    """A machine answered by the fast path and its twin answered by the reference, on one clock."""

    def __init__(self, profile: str, faults: FaultPlan | None = None) -> None:
        self.clock = FakeClock()
        self.fast = self._machine(profile)
        self.reference = self._machine(profile)
        self.faults = faults
        self.server = NativeServer(self.fast, faults)
        self.version = self.fast.profile.response_version

    def _machine(self, profile: str) -> MachineState:
        state = MachineState(profile, time_source=self.clock, cycle=CYCLE, seed=3, timezone="Europe/Berlin")
        for number in range(500, 520):
            state.write_macro(number, number / 8 - 60, protocol="setup")
        state.write_macro(130, 1e-7, protocol="setup")
        state.raise_alarm(1001, message="MANUAL")
        return state

    def at(self, seconds: float) -> Twins:
        self.clock.now = T0 + seconds
        return self

    def fast_reply(self, requests: list[RequestSubpacket]) -> bytes | type[Exception]:
        try:
            return self.server.answer_body(encode_request_body(requests), self.version)
        except ValueError:  # a payload beyond the u16 length, in both paths
            return ValueError

    def reference_reply(self, requests: list[RequestSubpacket]) -> bytes | type[Exception]:
        ctx = Context.from_sysinfo(self.reference.sysinfo())
        answers = [answer_subpacket(self.reference, req, self.faults, ctx) for req in requests]
        try:
            return encode_response(answers, self.version)
        except ValueError:
            return ValueError

    def assert_same(self, requests: list[RequestSubpacket]) -> bytes | type[Exception]:
        fast = self.fast_reply(requests)
        assert fast == self.reference_reply(requests), requests
        assert self.fast.write_log == self.reference.write_log
        return fast


def _requests_for(profile: str) -> Iterator[RequestSubpacket]:
    """Valid and invalid requests for every function the simulator handles, plus the odd ones."""
    max_axis = get_profile(profile).sysinfo.max_axis
    yield from (fn.SYSINFO.request(), fn.STATINFO.request(), fn.ALARM_STATUS.request(),
                fn.PROGRAM_NUMBER.request(), fn.SEQUENCE_NUMBER.request(), fn.EXEC_PROGRAM_NAME.request(),
                fn.MAIN_PROGRAM_PATH.request(), fn.ACTUAL_FEED.request(), fn.ACTUAL_SPINDLE_SPEED.request(),
                fn.AXIS_NAMES.request(), fn.SPINDLE_NAMES.request(), fn.SERVO_METER.request(1))
    for count in (-1, 0, 1, 10):
        yield fn.alarm_messages_request(count)
    yield fn.ALARM_MESSAGES.request(-1, 10, 2, 0)
    yield fn.ALARM_MESSAGES.request(7, 10, 2, 64)
    yield fn.ALARM_MESSAGES.request(-1, 10, 2, 70_000)  # too long for one subpacket
    for start, count in ((1, 19), (1235, 2), (99999, 5), (1, 0)):
        yield fn.PROGRAM_DIRECTORY.request(start, count, 2)
    for kind, spindle in ((4, -1), (4, 0), (4, 1), (4, 2), (4, 3)):
        yield fn.SPINDLE_LOAD.request(kind, spindle)
    for kind in (4, 0, 1, 6, 2, 7, 3, 99):
        for axis in (-1, 0, 1, 3, 6):
            yield fn.POSITIONS.request(kind, axis)
    for what in (0, 1, 2, 3):
        yield fn.CONTROLLED_AXES.request(what)
    for function in (fn.READ_PARAMS_4, fn.READ_PARAMS_8):
        for first, last, axis in ((6711, 6711, 0), (0, 9999, -1), (1020, 1022, 2), (1320, 1321, 0),
                                  (1, 5, 0), (6711, 6713, 9), (1005, 1005, -2)):
            yield function.request(first, last, axis)
    for function in (fn.READ_DIAG_4, fn.READ_DIAG_8):
        for first, last, axis in ((0, 999, -1), (300, 309, 1), (410, 411, 0), (5, 6, 0)):
            yield function.request(first, last, axis)
    for first, last in ((500, 500), (500, 519), (100, 199), (130, 130), (199, 500), (10, 12), (600, 599),
                        (998, 1000)):
        yield fn.read_macros_request(first, last) if last >= first else fn.READ_MACROS.request(first, last)
    yield fn.write_macros_request(540, [1.5, None, -2.25])
    yield fn.write_macros_request(198, [1.0, 2.0, 3.0])  # runs off the end of #100-#199
    yield fn.WRITE_MACROS.request(541, 542, extra=encode_scaled(4.0))  # extra too short
    yield fn.write_macro_double_request(545, 12.345)
    yield fn.write_macro_double_request(545, math.inf)
    yield fn.WRITE_MACRO_DOUBLE.request(546, extra=b"\x00" * 4)
    for area, start, end, dtype in (("R", 100, 103, 0), ("D", 2204, 2207, 1), ("G", 0, 7, 0), ("F", 0, 3, 0),
                                    ("Y", 0, 0, 0), ("D", 2204, 2207, 2), ("D", 2204, 2211, 4),
                                    ("D", 2204, 2211, 5), ("D", 2204, 2206, 1), ("R", 5, 4, 0),
                                    ("R", 5, 3, 1), ("X", 126, 129, 0), ("E", 0, 3, 0), ("K", 0, 3, 9)):
        yield fn.read_pmc_request(area, start, end, dtype)
    yield fn.READ_PMC.request(0, 3, 42, 0)  # unknown address type
    yield fn.write_pmc_request("R", 200, b"\x01\x02")
    yield fn.write_pmc_request("R", 0, bytes(33))
    yield fn.WRITE_PMC.request(10, 12, fn.pmc_adr_type("R"), 0, extra=b"\x01")
    yield fn.write_pmc_request("Y", 0, b"\xfe")  # the next refresh puts the coolant bit back
    yield from fn.read_clock_requests()
    yield fn.READ_CLOCK.request(2)
    yield fn.set_time_request(time(6, 30, 15))
    yield fn.SET_TIME.request(0, extra=bytes(12))
    yield fn.SET_TIME.request(1, extra=struct.pack(">6h", 0, 0, 0, 25, 0, 0))
    yield fn.SET_TIME.request(1, extra=bytes(4))
    for kind in (0, 1, 2, 3, 4, 5, -1):
        yield fn.READ_TIMER.request(kind)
    for first, last, kind in ((1, 4, 0), (1, 64, 3), (60, 70, 1), (0, 2, 2), (1, 1, 4)):
        yield fn.TOOL_OFFSETS.request(first, last, kind)
    yield fn.OPERATOR_MESSAGES.request()
    yield fn.STATINFO.request(path=2)  # wrong path
    yield fn.READ_MACROS.request(500, 500, path=0)
    yield RequestSubpacket(CLASS_CNC, 0x7777)  # unknown command
    yield RequestSubpacket(CLASS_PMC, fn.STATINFO.command)  # known command, wrong class
    yield RequestSubpacket(CLASS_CNC, fn.READ_PMC.command, (0, 3, 5, 0, 0))
    yield fn.READ_MACROS.request(500, 501, extra=b"\x01\x02")  # a read with stray extra bytes
    assert max_axis > 0


def test_the_cases_cover_every_function_the_simulator_handles() -> None:
    commands = {(req.cls, req.command) for req in _requests_for("30i")}
    assert {(function.cls, function.command) for function in HANDLERS} <= commands


@pytest.mark.parametrize("batch", [1, 32], ids=["each-request-alone", "whole-batches"])
@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_requests_answer_the_reference_bytes_at_every_moment(profile: str, batch: int) -> None:
    twins = Twins(profile)
    requests = list(_requests_for(profile))
    for moment in MOMENTS:
        twins.at(moment)
        for start in range(0, len(requests), batch):
            twins.assert_same(requests[start : start + batch])


def test_a_batch_with_one_oversized_answer_still_applies_every_write_then_fails_like_the_reference() -> None:
    twins = Twins("30i").at(1.0)
    oversized = fn.ALARM_MESSAGES.request(-1, 10, 2, 70_000)
    assert twins.assert_same([oversized, fn.write_macros_request(560, [7.0])]) is ValueError
    assert twins.fast.read_macro(560) == 7.0


def test_a_repeated_request_answers_the_state_of_its_moment_not_a_remembered_one() -> None:
    twins = Twins("30i")
    polls = [fn.STATINFO.request(), fn.positions_request("absolute"), fn.read_macros_request(500, 500),
             fn.read_pmc_request("F", 0, 1, PmcType.BYTE), *fn.read_clock_requests()]
    before = twins.at(0.5).assert_same(polls)
    for machine in (twins.fast, twins.reference):
        machine.write_macro(500, 99.5, protocol="test")
        machine.set_emergency(True)
    after = twins.at(2.0).assert_same(polls)
    assert before != after
    assert isinstance(after, bytes)
    answers = decode_response_body(decode_frame(after).body)
    assert fn.READ_MACROS.decode_response(answers[2], polls[2], twins.server.context) == [99.5]


@pytest.mark.parametrize("faults", [
    FaultPlan(ew={"read_macros": 6, 0x19: 17}),
    FaultPlan(ew={0x8001: 18}),
    FaultPlan(ew={"0x7777": 4}),
], ids=["by-name-and-code", "pmc", "unknown-command"])
def test_forced_ew_codes_answer_as_the_reference(faults: FaultPlan) -> None:
    twins = Twins("30i", faults)
    requests = list(_requests_for("30i"))
    twins.at(3.0)
    for start in range(0, len(requests), 32):
        twins.assert_same(requests[start : start + 32])
    reply = twins.fast_reply([fn.read_macros_request(500, 500), fn.STATINFO.request()])
    assert isinstance(reply, bytes)
    rcs = [sub.rc for sub in decode_response_body(decode_frame(reply).body)]
    assert rcs == [faults.ew.get("read_macros", 0), faults.ew.get(0x19, 0)]


def test_an_ew_fault_set_after_the_plans_were_compiled_applies_at_once() -> None:
    twins = Twins("30i").at(1.0)
    poll = [fn.read_macros_request(500, 500), fn.STATINFO.request()]
    twins.assert_same(poll)
    twins.server.faults.ew = {"read_macros": 6}
    reply = twins.fast_reply(poll)
    assert isinstance(reply, bytes)
    assert [sub.rc for sub in decode_response_body(decode_frame(reply).body)] == [6, 0]


RECORD_AND_TIMER_READS = [fn.READ_PARAMS_4.request(6711, 6711, 0), fn.READ_PARAMS_8.request(1320, 1321, -1),
                          fn.READ_PARAMS_8.request(6711, 6711, 0), fn.READ_DIAG_4.request(300, 300, -1),
                          fn.READ_TIMER.request(0)]


def _reference_with(twins: Twins, ctx: Context) -> bytes:
    answers = [answer_subpacket(twins.reference, req, None, ctx) for req in RECORD_AND_TIMER_READS]
    return encode_response(answers, twins.version)


def test_plans_follow_a_new_profile() -> None:
    twins = Twins("30i").at(2.0)
    first = twins.assert_same(RECORD_AND_TIMER_READS)
    for machine in (twins.fast, twins.reference):
        machine.profile = get_profile("16i")  # answers 0x0e/0x30, refuses 0x8d/0x93
    reply = twins.fast_reply(RECORD_AND_TIMER_READS)
    assert reply == _reference_with(twins, twins.server.context)
    assert reply != first


def test_plans_follow_a_new_context() -> None:
    twins = Twins("30i").at(2.0)
    first = twins.assert_same(RECORD_AND_TIMER_READS)
    twins.server.context = Context(max_axis=3, slot_form=SlotForm.SCALED)
    reply = twins.fast_reply(RECORD_AND_TIMER_READS)
    assert reply == _reference_with(twins, twins.server.context)
    assert reply != first


def test_server_counts_and_answers_a_data_pdu_through_the_plans() -> None:
    twins = Twins("16i").at(4.0)
    requests = [fn.STATINFO.request(), fn.read_macros_request(500, 509), fn.READ_PARAMS_8.request(6711, 6711, 0)]
    reply = twins.fast_reply(requests)
    assert isinstance(reply, bytes)
    rcs = [sub.rc for sub in decode_response_body(decode_frame(reply).body)]
    assert rcs == [0, 0, EW_FUNC]  # a 16i has the 4-byte record form only
    assert twins.server.plans.for_body(encode_request_body(requests), twins.server.context)[2].name == "read_params"
    path_error = twins.fast_reply([fn.STATINFO.request(path=3)])
    assert isinstance(path_error, bytes)
    assert decode_response_body(decode_frame(path_error).body)[0].rc == EW_PATH


# ---- the pieces the fast path relies on ----------------------------------------------------------------

FINITE = st.floats(allow_nan=False, allow_infinity=False)
SCALABLE = st.one_of(
    FINITE,
    st.floats(min_value=-3e9, max_value=3e9),
    st.decimals(min_value=-2_147_483, max_value=2_147_483, places=3, allow_nan=False,
                allow_infinity=False).map(float),
    st.decimals(min_value=-2, max_value=2, places=10, allow_nan=False, allow_infinity=False).map(float),
    st.integers(min_value=-(2**40), max_value=2**40),
    st.sampled_from([None, 0.0, -0.0, 0, 1e-7, 1e-5, 2147483647.0, 2147483648.0, -2147483648.0, 0.1 + 0.2,
                     math.nan, math.inf, -math.inf, 123456789.123, 1.0000000001, 0.1234567891, -0.0000012345,
                     5e-324, True, False]),
)


def _outcome(encode: Callable[[object], bytes], value: object) -> bytes | type[Exception]:
    try:
        return encode(value)
    except ValueError as exc:
        return type(exc)


@given(SCALABLE)
def test_scaled_bytes_is_encode_scaled(value: float | None) -> None:
    assert _outcome(scaled_bytes, value) == _outcome(encode_scaled, value)  # type: ignore[arg-type]
    assert _outcome(scaled_bytes, value) == _outcome(encode_scaled, value)  # type: ignore[arg-type]  # remembered


@given(st.lists(st.sampled_from([fn.STATINFO.request(), fn.write_pmc_request("R", 0, b"\x01\x02"),
                                 fn.read_macros_request(500, 509)]), max_size=5),
       st.binary(max_size=40), st.integers(min_value=0, max_value=200))
def test_malformed_bodies_fail_as_decode_request_body_does(requests: list[RequestSubpacket], noise: bytes,
                                                            cut: int) -> None:
    intact = encode_request_body(requests)
    server = NativeServer(MachineState("30i"))
    for body in (intact, intact[:cut], intact + noise, noise, intact[:2] + noise):
        try:
            expected: list[RequestSubpacket] | type[Exception] = decode_request_body(body)
        except ProtocolError as exc:
            expected = type(exc)
        try:
            plans = server.plans.for_body(body, server.context)
            got: list[RequestSubpacket] | type[Exception] = [plan.request for plan in plans]
        except ProtocolError as exc:
            got = type(exc)
        assert got == expected


ARGS = st.one_of(st.integers(min_value=-3, max_value=12), st.integers(min_value=95, max_value=1030),
                 st.integers(min_value=6700, max_value=6720), st.integers(min_value=-(2**31), max_value=2**31 - 1))


@st.composite
def _any_request(draw: st.DrawFn) -> RequestSubpacket:
    function = draw(st.sampled_from(list(fn.FUNCTIONS)))
    cls = draw(st.sampled_from([function.cls, function.cls, 3 - function.cls]))
    command = draw(st.sampled_from([function.command] * 4 + [0x7777, 0x0000]))
    args = tuple(draw(ARGS) for _ in range(4))
    extra = draw(st.sampled_from([b"", bytes(8), encode_scaled(2.5), bytes(range(1, 13)), b"\x7f\xf0" + bytes(6)]))
    path = draw(st.sampled_from([1, 1, 1, 2]))
    return RequestSubpacket(cls, command, (*args, len(extra)), extra, path)  # type: ignore[arg-type]


@given(st.sampled_from(sorted(PROFILES)), st.lists(_any_request(), min_size=1, max_size=6),
       st.sampled_from(MOMENTS))
def test_any_request_answers_the_reference_bytes(profile: str, requests: list[RequestSubpacket],
                                                 moment: float) -> None:
    twins = Twins(profile).at(moment)
    twins.assert_same(requests)
    twins.assert_same(requests)  # again, through the compiled plans


def test_the_fast_path_gives_ew_number_for_a_value_the_wire_cannot_carry() -> None:
    twins = Twins("30i").at(0.0)
    for machine in (twins.fast, twins.reference):
        machine._macros.values[501] = math.inf  # only possible from inside: write_macro refuses it
    reply = twins.assert_same([fn.read_macros_request(500, 502)])
    assert isinstance(reply, bytes)
    assert decode_response_body(decode_frame(reply).body)[0].rc == EW_NUMBER


def test_full_caches_start_over_and_answer_the_same(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ns, "PLAN_CACHE_LIMIT", 3)
    monkeypatch.setattr(ns, "SCALED_CACHE_LIMIT", 5)
    monkeypatch.setattr(ns, "_scaled_known", {})
    twins = Twins("0i-F")
    requests = list(_requests_for("0i-F"))
    for moment in MOMENTS[:3]:
        twins.at(moment)
        for request in requests:
            twins.assert_same([request])
    assert len(twins.server.plans._plans) <= 3
    assert len(ns._scaled_known) <= 5


def test_writes_are_answered_but_their_plans_not_kept() -> None:
    twins = Twins("30i").at(1.0)
    twins.assert_same([fn.read_macros_request(500, 500)])
    for value in (1.0, 2.0, 3.0):
        twins.assert_same([fn.write_macros_request(550, [value]), fn.read_macros_request(550, 550)])
    assert twins.fast.read_macro(550) == 3.0
    assert len(twins.server.plans._plans) == 2
