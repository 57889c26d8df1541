"""The function table: every function's payload round-trips, server and client agree, errors are typed."""

from __future__ import annotations

import contextlib
import struct
from datetime import date, datetime, time
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.focas import function_entry as fe
from edge.focas import functions as fn
from edge.focas import items as it
from edge.focas.errors import AccessDenied, FocasError, FunctionNotAvailable, NotSupported, OutOfRange, ProtocolError
from edge.focas.frame import ResponseSubpacket
from edge.focas.function_entry import Context, Function
from edge.focas.model import (
    ActiveAlarm,
    ExecProgram,
    OperatorMessage,
    ParamRecord,
    PmcType,
    ProgramDirEntry,
    ProgramNumbers,
    StatInfo,
    SysInfo,
    TimerValue,
)
from edge.focas.native import SUPPORTED_ITEMS, clock_value, item_result, item_value, plan_item, pmc_byte_end
from edge.focas.values import SlotForm

CTX16 = Context(max_axis=8, slot_form=SlotForm.FOUR_BYTE)
CTX30 = Context(max_axis=32, slot_form=SlotForm.SCALED)
SYSINFO_30I = SysInfo(0x0200, 32, "31", " M", "G421", "08.0", "04")

# (function, request args, value, context): value -> encode_payload -> decode_payload == value
ROUND_TRIPS: list[tuple[Function, tuple[int, ...], Any, Context]] = [
    (fn.SYSINFO, (), SYSINFO_30I, CTX16),
    (fn.STATINFO, (), StatInfo(1, 3, 1, 0, 0, 0, 0), CTX16),
    (fn.ALARM_STATUS, (), 0x0002, CTX16),
    (fn.ALARM_MESSAGES, (-1, 10, 2, 64),
     [ActiveAlarm(1001, 2, 0, "SPINDLE OVERHEAT"), ActiveAlarm(500, 4, 1, "OVER TRAVEL +X")], CTX16),
    (fn.PROGRAM_NUMBER, (), ProgramNumbers(3000, 3000), CTX16),
    (fn.SEQUENCE_NUMBER, (), 120, CTX16),
    (fn.EXEC_PROGRAM_NAME, (), ExecProgram(1234, "O1234"), CTX16),
    (fn.MAIN_PROGRAM_PATH, (), "//CNC_MEM/USER/PATH1/O1234", CTX16),
    (fn.PROGRAM_DIRECTORY, (1, 19, 2), [ProgramDirEntry(1, 420, "(MAIN)"), ProgramDirEntry(9000, 80, "")],
     CTX16),
    (fn.ACTUAL_FEED, (), 1250.5, CTX16),
    (fn.ACTUAL_SPINDLE_SPEED, (), None, CTX16),
    (fn.SPINDLE_LOAD, (4, -1), [12.0, None], CTX16),
    (fn.POSITIONS, (4, -1), [311.1657, -0.3, 126.5, None], CTX16),
    (fn.AXIS_NAMES, (), ["X", "Y", "Z", "B"], CTX16),
    (fn.SPINDLE_NAMES, (), ["S1", "S2"], CTX16),
    (fn.SERVO_METER, (1,), [10.0, 0.0, 5.5], CTX16),
    (fn.CONTROLLED_AXES, (2,), 4, CTX16),
    (fn.READ_PARAMS_4, (3401, 3401, 0), [ParamRecord(3401, 0, 0, (2,))], CTX16),
    (fn.READ_PARAMS_8, (6711, 6711, 0), [ParamRecord(6711, 0, 3, (52638,))], CTX30),
    (fn.READ_DIAG_4, (980, 981, 1), [ParamRecord(980, 1, 2, (-598358,)), ParamRecord(981, 1, 2, (7,))],
     CTX16),
    (fn.READ_DIAG_8, (918, 918, 0), [ParamRecord(918, 0, 4, (1.25,))], CTX30),
    (fn.READ_MACROS, (500, 502), [1.25, None, -3.0], CTX16),
    (fn.READ_PMC, (2204, 2207, 9, 1), [600, -1], CTX16),
    (fn.READ_PMC, (100, 102, 5, 0), [1, 2, 255], CTX16),
    (fn.READ_PMC, (0, 7, 9, 5), [2.5], CTX16),
    (fn.READ_CLOCK, (0,), date(2020, 5, 14), CTX16),
    (fn.READ_CLOCK, (1,), time(12, 15, 5), CTX16),
    (fn.READ_TIMER, (0,), TimerValue(123456, 59999), CTX16),
    (fn.TOOL_OFFSETS, (1, 3, 0), [102.5, 105.0, None], CTX16),
    (fn.OPERATOR_MESSAGES, (), [OperatorMessage(2001, 0, "LOAD NEXT BLANK")], CTX16),
    (fn.OPERATOR_MESSAGES, (), [], CTX16),
]


@pytest.mark.parametrize("function,args,value,ctx", ROUND_TRIPS, ids=lambda x: getattr(x, "name", None))
def test_payload_round_trip(function: Function, args: tuple[int, ...], value: Any, ctx: Context) -> None:
    req = function.request(*args)
    sub = function.response(req, value, ctx)
    assert sub.answers(req) and sub.rc == 0
    assert function.decode_response(sub, req, ctx) == value


def test_every_read_function_has_a_round_trip() -> None:
    covered = {f.command for f, *_ in ROUND_TRIPS}
    reads = {f.command for f in fn.FUNCTIONS if not f.is_write}
    assert reads <= covered


def test_table_is_unique_and_documented() -> None:
    assert len(fn.BY_COMMAND) == len(fn.FUNCTIONS)
    for function in fn.FUNCTIONS:
        assert function.layout and function.returns and function.evidence in fe.Evidence
        assert function.cls in (1, 2)


def test_clock_datetime_fills_both_halves() -> None:
    date_req, time_req = fn.read_clock_requests()
    payload = fn.READ_CLOCK.encode_payload(datetime(2024, 2, 29, 23, 59, 58), date_req, CTX16)
    assert payload.hex() == "07e80002001d0017003b003a"
    assert fn.READ_CLOCK.decode_payload(payload, date_req, CTX16) == date(2024, 2, 29)
    assert fn.READ_CLOCK.decode_payload(payload, time_req, CTX16) == time(23, 59, 58)
    with pytest.raises(ProtocolError, match="expected arg1 0 \\(date\\) or 1 \\(time\\)"):
        fn.READ_CLOCK.decode_payload(payload, fn.READ_CLOCK.request(2), CTX16)


def test_timer_little_endian_fallback() -> None:
    req = fn.READ_TIMER.request(1)
    big = struct.pack(">ii", 100000, 1234)
    little = struct.pack("<ii", 100000, 1234)
    assert fn.READ_TIMER.decode_payload(big, req, CTX16) == TimerValue(100000, 1234)
    assert fn.READ_TIMER.decode_payload(little, req, CTX16) == TimerValue(100000, 1234)
    with pytest.raises(ProtocolError, match="either byte order"):
        fn.READ_TIMER.decode_payload(struct.pack(">ii", -5, 70000), req, CTX16)


def test_alarm_message_text_is_cut_at_msg_len() -> None:
    req = fn.alarm_messages_request(5, text_len=8)
    payload = struct.pack(">iiii", 1001, 2, 0, 3) + b"ABCDEFGH"
    assert fn.ALARM_MESSAGES.decode_payload(payload, req, CTX16) == [ActiveAlarm(1001, 2, 0, "ABC")]
    with pytest.raises(ProtocolError, match="records of 24 bytes"):
        fn.ALARM_MESSAGES.decode_payload(payload + b"\x00", req, CTX16)


def test_operator_message_fields_sit_where_hslcommunication_reads_them() -> None:
    """HslCommunication reads i16 number at record byte 2, type at 6, text length at 10, text at 12 (the
    low halves of three big-endian i32); bytes after the first message's text are not interpreted."""
    payload = bytes.fromhex("000007d1" "00000000" "00000005") + b"HELLO" + b"\x00" * 7
    req = fn.OPERATOR_MESSAGES.request()
    sub = ResponseSubpacket(1, 0x34, 0, 0, payload)
    assert fn.OPERATOR_MESSAGES.decode_response(sub, req, CTX16) == [OperatorMessage(2001, 0, "HELLO")]
    with pytest.raises(ProtocolError, match="operator message"):
        fn.OPERATOR_MESSAGES.decode_response(ResponseSubpacket(1, 0x34, 0, 0, b"\x00" * 6), req, CTX16)


def test_tool_offset_count_must_match() -> None:
    req = fn.TOOL_OFFSETS.request(1, 3, 1)
    sub = ResponseSubpacket(1, 0x08, 0, 0, fn.encode_scaled_list([0.01, 0.02]))
    with pytest.raises(ProtocolError, match="expected 3 values"):
        fn.TOOL_OFFSETS.decode_response(sub, req, CTX16)


def test_names_use_the_first_character_cells() -> None:
    payload = b"X\x00\x00\x00Y\x00\x00\x00\x00\x00\x00\x00"
    assert fn.AXIS_NAMES.decode_payload(payload, fn.AXIS_NAMES.request(), CTX16) == ["X", "Y"]


def test_macro_count_must_match() -> None:
    assert fn.READ_MACROS.decode_payload(bytes(8), fn.read_macros_request(1, 1), CTX16) == [0.0]
    with pytest.raises(ProtocolError, match="expected 3 values, got 1"):
        fn.READ_MACROS.decode_payload(fn.encode_scaled(1.0), fn.read_macros_request(1, 3), CTX16)


def test_pmc_length_must_match_the_range() -> None:
    with pytest.raises(ProtocolError, match="expected 2 bytes, got 4"):
        fn.READ_PMC.decode_payload(bytes(4), fn.read_pmc_request("D", 0, 1, 1), CTX16)


def test_cnc_error_becomes_typed_exception() -> None:
    req = fn.STATINFO.request()
    with pytest.raises(FunctionNotAvailable) as caught:
        fn.STATINFO.decode_response(fe.error_response(req, 1, 7), req, CTX16)
    assert (caught.value.code, caught.value.name, caught.value.function, caught.value.detail) == \
        (1, "EW_FUNC", "statinfo", 7)
    assert isinstance(caught.value, NotSupported)
    with pytest.raises(AccessDenied):
        fn.WRITE_PMC.decode_response(fe.error_response(req, 17), req, CTX16)
    assert fe.error_response(req, 1).encode().hex() == "00100001000100190001000000000000"


def test_write_requests_carry_their_values_to_the_server() -> None:
    req = fn.write_macros_request(500, [1.25, None])
    assert req.args == (500, 501, 0, 0, 16)
    assert fn.WRITE_MACROS.decode_extra is not None
    assert fn.WRITE_MACROS.decode_extra(req, CTX16) == [1.25, None]
    pmc = fn.write_pmc_request("G", 10, b"\x01\x02\x03")
    assert fn.WRITE_PMC.named_args(pmc) == {"start": 10, "end": 12, "adr_type": 0, "data_type": 0}
    assert fn.WRITE_PMC.decode_extra is not None
    bad = fn.WRITE_PMC.request(10, 20, 0, 0, extra=b"\x01")
    with pytest.raises(ProtocolError, match="expected 11 data bytes, got 1"):
        fn.WRITE_PMC.decode_extra(bad, CTX16)


def test_pmc_area_codes() -> None:
    assert [fn.pmc_adr_type(a) for a in "GFYXARTKCDMNEZ"] == list(range(14))
    with pytest.raises(ValueError, match="unknown PMC area 'Q'"):
        fn.pmc_adr_type("Q")


@given(st.sampled_from([f for f in fn.FUNCTIONS if not f.is_write]), st.binary(max_size=300),
       st.lists(st.integers(-(2**31), 2**31 - 1), min_size=4, max_size=4),
       st.sampled_from([CTX16, CTX30, Context(max_axis=3)]))
def test_random_payloads_only_raise_protocol_error(function: Function, payload: bytes, args: list[int],
                                                   ctx: Context) -> None:
    req = function.request(*args)
    with contextlib.suppress(ProtocolError):
        function.decode_payload(payload, req, ctx)


@given(st.sampled_from([f for f in fn.FUNCTIONS if f.is_write]), st.binary(max_size=64),
       st.lists(st.integers(-(2**31), 2**31 - 1), min_size=4, max_size=4))
def test_random_write_extras_only_raise_protocol_error(function: Function, extra: bytes,
                                                       args: list[int]) -> None:
    assert function.decode_extra is not None
    with contextlib.suppress(ProtocolError):
        function.decode_extra(function.request(*args, extra=extra), CTX16)


# ---- item planning (native.py) -----------------------------------------------------------------------


def test_pmc_end_covers_whole_elements() -> None:
    assert pmc_byte_end(2204, 2204, 2) == 2205
    assert pmc_byte_end(2204, 2205, 2) == 2205
    assert pmc_byte_end(100, 103, 1) == 103
    assert pmc_byte_end(0, 5, 4) == 7


def test_param_form_follows_the_context() -> None:
    assert plan_item(it.ReadParams(6711, 6711), CTX30).calls[0][0] is fn.READ_PARAMS_8
    assert plan_item(it.ReadParams(6711, 6711), CTX16).calls[0][0] is fn.READ_PARAMS_4
    assert plan_item(it.ReadDiag(918, 918), CTX30).calls[0][0] is fn.READ_DIAG_8
    assert plan_item(it.ReadDiag(918, 918), CTX16).calls[0][0] is fn.READ_DIAG_4


def test_clock_is_two_subpackets_combined() -> None:
    plan = plan_item(it.ReadClock(), CTX16)
    assert [req.args[0] for req in plan.requests] == [0, 1]
    when = datetime(2025, 1, 2, 3, 4, 5)
    answers = [fn.READ_CLOCK.response(req, when, CTX16) for req in plan.requests]
    assert item_result(plan, answers, CTX16) == when
    answers[1] = fe.error_response(plan.requests[1], 6)
    assert isinstance(item_result(plan, answers, CTX16), FunctionNotAvailable)


_I16 = st.integers(-(2**15), 2**15 - 1)


_DAYS = st.one_of(st.dates(max_value=date(9999, 12, 31)).map(lambda d: (d.year, d.month, d.day)),
                  st.tuples(_I16, _I16, _I16))
_TIMES = st.one_of(st.times().map(lambda t: (t.hour, t.minute, t.second)), st.tuples(_I16, _I16, _I16))


@given(_DAYS, _TIMES, st.sampled_from([0, 0, 0, 6, -8]),
       st.sampled_from([12, 12, 12, 10, 14]))
def test_the_clock_in_one_decode_is_the_clock_of_two(day: tuple[int, int, int], clock: tuple[int, int, int],
                                                     rc: int, size: int) -> None:
    """clock_value (the client's one-step decode) gives item_value's datetime for every good answer and None for
    any other, which the client then hands to item_value for its error."""
    plan = plan_item(it.ReadClock(), CTX16)
    date_payload = struct.pack(">6h", *day, -1, 99, 77)[:size].ljust(size, b"\0")  # the other half: not read
    time_payload = struct.pack(">6h", 0, 13, 99, *clock)
    answers = [(0, 0, date_payload), (rc, 0, time_payload if rc == 0 else b"")]
    slow = item_value(plan, answers, 0, CTX16)
    fast = clock_value(*answers)
    if fast is None:
        assert isinstance(slow, FocasError), slow
    else:
        assert fast == slow and type(fast) is datetime


def test_items_without_wire_code_or_with_bad_arguments() -> None:
    history = item_result(plan_item(it.ReadAlarmHistory(), CTX16), [], CTX16)
    assert isinstance(history, NotSupported) and "no public" in str(history)
    bad_area = item_result(plan_item(it.ReadPmc("Q", 0, 0), CTX16), [], CTX16)
    assert isinstance(bad_area, OutOfRange)
    bad_kind = item_result(plan_item(it.ReadPositions("skip"), CTX16), [], CTX16)
    assert isinstance(bad_kind, OutOfRange)


def test_every_item_class_is_planned() -> None:
    samples = [it.ReadSysInfo(), it.ReadStatus(), it.ReadAlarmStatus(), it.ReadActiveAlarms(),
               it.ReadProgramNumber(), it.ReadSequenceNumber(), it.ReadExecProgramName(),
               it.ReadMainProgramPath(), it.ReadProgramDirectory(), it.ReadFeed(), it.ReadSpindleSpeed(),
               it.ReadSpindleLoad(), it.ReadPositions("machine"), it.ReadAxisNames(), it.ReadSpindleNames(),
               it.ReadServoMeter(), it.ReadControlledAxes(), it.ReadParams(1, 2), it.ReadDiag(1, 2),
               it.ReadMacros(1, 2), it.ReadPmc("D", 0, 3, PmcType.WORD), it.ReadClock(), it.ReadTimer(1),
               it.ReadToolOffsets(1, 1, 4), it.ReadOperatorMessages(), it.ReadPathStatus(2)]
    all_items = {cls.__name__ for cls in vars(it).values()
                 if isinstance(cls, type) and issubclass(cls, it.ReadItem) and cls is not it.ReadItem}
    no_wire_form = {"ReadAlarmHistory", "ReadWorkOffsets", "ReadModalGCodes", "ReadToolNumber"}
    assert {s.operation for s in samples} == SUPPORTED_ITEMS == all_items - no_wire_form
    for item in samples:
        plan = plan_item(item, CTX16)
        assert plan.error is None and plan.calls, item


def test_unused_response_fields() -> None:
    # a payload-less OK answer to a write decodes to None
    req = fn.write_pmc_request("R", 0, b"\x01")
    assert fn.WRITE_PMC.decode_response(ResponseSubpacket(2, 0x8002), req, CTX16) is None


def test_little_endian_timer_with_zero_msec_is_recognised() -> None:
    """A 31i-B sends the timer little-endian; msec 0 must not make it look big-endian."""
    import struct

    from edge.focas import functions as fn
    from edge.focas.model import TimerValue

    req = fn.READ_TIMER.request(0)
    for minutes in (1, 100, 123_457, 5_000_001):
        payload = struct.pack("<ii", minutes, 0)
        assert fn._timer_decode(payload, req, fe.Context(8)) == TimerValue(minutes, 0)
    assert fn._timer_decode(struct.pack(">ii", 100, 0), req, fe.Context(8)) == TimerValue(100, 0)
