"""Byte-level tests of the packed-buffer surface, built from the seed's tables (seeds 000-002)."""

from __future__ import annotations

import struct
from datetime import UTC, datetime, timedelta, timezone

import pytest

from edge.focas import packed as pk
from edge.focas.errors import (
    AccessDenied,
    CncError,
    FunctionNotAvailable,
    LengthError,
    OutOfRange,
    ProtocolError,
)
from edge.focas.model import (
    ActiveAlarm,
    AlarmHistoryEntry,
    ParamRecord,
    ParamType,
    PmcType,
    ProgramNumbers,
    StatInfo,
    SysInfo,
    TimerValue,
)


def h(text: str) -> bytes:
    return bytes.fromhex(text)


def entry_bytes(year: int, month: int, day: int, hour: int, minute: int, second: int, axis: int,
                atype: int, number: int, message: bytes, msg_len: int | None = None,
                pad: bool = True) -> bytes:
    """One ODBALMHIS entry straight from the seed's table: ten int16 LE, message, pad to 4."""
    length = len(message) if msg_len is None else msg_len
    block = struct.pack("<10h", year, month, day, hour, minute, second, axis, atype, number, length) + message
    return block + (b"\x00" * (-len(message) % 4) if pad else b"")


# ---- command table ------------------------------------------------------------------------------------
def test_seed_command_ids_are_fixed() -> None:
    assert pk.Command.RDCNCSTAT == 0x0001
    assert pk.Command.RDPARAM == 0x0002
    assert pk.Command.RDMACRO == 0x0003
    assert pk.Command.RDDIAG == 0x0004
    assert pk.Command.WRPARAM == 0x0102
    assert pk.Command.WRMACRO == 0x0103
    assert pk.Command.WRPMCRNG == 0x0104
    assert pk.Command.RDALMHISTRY == 0x0F1A


def test_extension_ids_avoid_the_seed_blocks_and_reserved_ids() -> None:
    seed = {0x0001, 0x0002, 0x0003, 0x0004, 0x0102, 0x0103, 0x0104, 0x0F1A}
    extensions = {int(c) for c in pk.Command} - seed
    assert extensions, "the daemon's extra reads need ids"
    assert all(0x4000 < c < 0x5000 for c in extensions)
    assert not extensions & set(pk.RESERVED_IDS)
    assert len({int(c) for c in pk.Command}) == len(pk.Command)  # no alias: every id distinct
    assert set(pk.FOCAS_NAMES) == set(pk.Command)


def test_command_name_of_unknown_id() -> None:
    assert pk.command_name(0x0F1A) == "cnc_rdalmhistry"
    assert pk.command_name(0x7777) == "packed-0x7777"


# ---- statuses ------------------------------------------------------------------------------------------
def test_write_response_zero_is_good() -> None:
    pk.decode_status(h("0000"), pk.Command.WRPARAM)


@pytest.mark.parametrize("status", [11, 17])
def test_status_11_on_this_surface_and_17_are_access_denied(status: int) -> None:
    with pytest.raises(AccessDenied) as info:
        pk.decode_status(struct.pack("<h", status), pk.Command.WRPARAM)
    assert info.value.name == "EW_PASSWD"
    assert info.value.function == "cnc_wrparam"
    assert f"status {status}" in str(info.value)


@pytest.mark.parametrize(
    ("status", "kind", "name"),
    [(6, FunctionNotAvailable, "EW_NOOPT"), (3, OutOfRange, "EW_NUMBER"), (2, LengthError, "EW_LENGTH")],
)
def test_noopt_number_length_are_distinct_errors(status: int, kind: type[CncError], name: str) -> None:
    with pytest.raises(kind) as info:
        pk.decode_status(struct.pack("<h", status), pk.Command.WRPMCRNG)
    assert info.value.name == name
    assert info.value.code == status


def test_other_status_is_a_plain_cnc_error() -> None:
    with pytest.raises(CncError) as info:
        pk.decode_status(h("0500"), pk.Command.WRMACRO)
    assert type(info.value) is CncError and info.value.code == 5


@pytest.mark.parametrize("payload", ["", "00", "000000"])
def test_write_response_must_be_exactly_one_int16(payload: str) -> None:
    with pytest.raises(ProtocolError, match="2-byte status"):
        pk.decode_status(h(payload), pk.Command.WRMACRO)


# ---- ODBALMHIS (0x0F1A) ----------------------------------------------------------------------------------
@pytest.mark.parametrize(("depth", "wire"), [(100, "6400"), (1, "0100"), (250, "fa00"), (0, "0100"),
                                             (-7, "0100"), (251, "fa00"), (10_000, "fa00")])
def test_history_request_depth_is_clamped_to_1_250(depth: int, wire: str) -> None:
    assert pk.encode_alarm_history_request(depth) == h(wire)


def test_history_request_decoding_clamps_too() -> None:
    assert pk.decode_alarm_history_request(h("0000")) == 1
    assert pk.decode_alarm_history_request(h("e803")) == 250
    assert pk.decode_alarm_history_request(h("0a00")) == 10
    assert pk.decode_alarm_history_request(b"") == 250


def test_history_entry_layout_matches_the_seed_table() -> None:
    entry = AlarmHistoryEntry(datetime(2026, 4, 25, 13, 45, 10, tzinfo=UTC), 2, 4, 500, "OT")
    wire = pk.encode_alarm_history([entry])
    assert wire == h(
        "0100"  # num_alm
        "ea07" "0400" "1900" "0d00" "2d00" "0a00"  # 2026-04-25 13:45:10
        "0200" "0400" "f401" "0200"  # axis 2, type 4, alm_no 500, msg_len 2
        "4f54" "0000"  # "OT" + 2 pad bytes (20 + 2 + 2 = 24)
    )
    assert pk.decode_alarm_history(wire) == [entry]


@pytest.mark.parametrize("msg_len", range(8))
def test_history_padding_for_msg_len_0_to_7(msg_len: int) -> None:
    message = "ABCDEFG"[:msg_len]
    entry = AlarmHistoryEntry(datetime(2025, 1, 2, 3, 4, 5, tzinfo=UTC), 0, 1, 1000 + msg_len, message)
    wire = pk.encode_alarm_history([entry, entry])
    block = 20 + msg_len + (-msg_len % 4)
    assert block % 4 == 0 and block - 20 - msg_len in range(4)
    assert len(wire) == 2 + 2 * block
    pad = wire[2 + 20 + msg_len : 2 + block]
    assert pad == b"\x00" * (block - 20 - msg_len)
    assert wire[2 + block : 2 + block + 2] == struct.pack("<h", 2025)  # the second entry starts after the pad
    assert pk.decode_alarm_history(wire) == [entry, entry]
    assert pk.encode_alarm_history(pk.decode_alarm_history(wire)) == wire


def test_history_timestamps_are_utc_and_tz_aware() -> None:
    wire = h("0100") + entry_bytes(2024, 10, 27, 2, 30, 0, 0, 1, 10, b"")
    (entry,) = pk.decode_alarm_history(wire)
    assert entry.occurred.tzinfo is UTC
    assert entry.occurred == datetime(2024, 10, 27, 2, 30, tzinfo=UTC)


def test_history_encoder_converts_aware_times_to_utc() -> None:
    local = datetime(2026, 1, 1, 10, 0, 0, tzinfo=timezone(timedelta(hours=2)))
    wire = pk.encode_alarm_history([AlarmHistoryEntry(local, 0, 1, 2, "")])
    (entry,) = pk.decode_alarm_history(wire)
    assert entry.occurred == datetime(2026, 1, 1, 8, 0, 0, tzinfo=UTC)


@pytest.mark.parametrize("num_alm", [-1, -2, -32768])
def test_history_negative_num_alm_is_an_empty_list(num_alm: int) -> None:
    # even when well-formed entries follow: a negative count is a CNC error ("no history this tick")
    wire = struct.pack("<h", num_alm) + entry_bytes(2026, 1, 1, 0, 0, 0, 0, 1, 2, b"X")
    assert pk.decode_alarm_history(wire) == []


def test_history_zero_entries() -> None:
    assert pk.decode_alarm_history(h("0000")) == []
    assert pk.encode_alarm_history([]) == h("0000")


@pytest.mark.parametrize(
    "bad_time",
    [(2026, 0, 1, 0, 0, 0), (2026, 13, 1, 0, 0, 0), (2026, 2, 30, 0, 0, 0), (2026, 1, 1, 24, 0, 0),
     (2026, 1, 1, 0, 60, 0), (2026, 1, 1, 0, 0, 60), (0, 1, 1, 0, 0, 0), (-5, 1, 1, 0, 0, 0)],
)
def test_history_malformed_timestamp_skips_that_entry_only(bad_time: tuple[int, int, int, int, int, int]) -> None:
    wire = (h("0300")
            + entry_bytes(2026, 3, 1, 8, 0, 0, 1, 2, 100, b"FIRST")
            + entry_bytes(*bad_time, 0, 2, 200, b"BAD")
            + entry_bytes(2026, 3, 1, 6, 0, 0, 0, 3, 300, b"THIRD"))
    entries = pk.decode_alarm_history(wire)
    assert [(e.alm_no, e.message) for e in entries] == [(100, "FIRST"), (300, "THIRD")]


def test_history_msg_len_past_the_payload_truncates_at_that_entry() -> None:
    first = entry_bytes(2026, 3, 1, 8, 0, 0, 1, 2, 100, b"OK")
    overrun = entry_bytes(2026, 3, 1, 7, 0, 0, 0, 2, 200, b"SHORT", msg_len=40)
    after = entry_bytes(2026, 3, 1, 6, 0, 0, 0, 3, 300, b"NEVER")
    # the overrunning entry claims 40 bytes; 5 + pad + the next entry's 28 bytes are only 36
    wire = h("0300") + first + overrun + after
    assert [e.alm_no for e in pk.decode_alarm_history(wire)] == [100]


def test_history_negative_msg_len_truncates_too() -> None:
    wire = h("0200") + entry_bytes(2026, 1, 1, 0, 0, 0, 0, 1, 1, b"") + entry_bytes(
        2026, 1, 1, 0, 0, 0, 0, 1, 2, b"", msg_len=-4)
    assert [e.alm_no for e in pk.decode_alarm_history(wire)] == [1]


def test_history_more_entries_announced_than_sent_keeps_the_whole_ones() -> None:
    whole = entry_bytes(2026, 1, 1, 0, 0, 0, 0, 1, 1, b"A")
    assert [e.alm_no for e in pk.decode_alarm_history(h("0500") + whole + whole[:11])] == [1]


def test_history_last_entry_without_padding_is_kept() -> None:
    wire = h("0100") + entry_bytes(2026, 1, 1, 0, 0, 0, 0, 1, 7, b"ABC", pad=False)
    assert [e.message for e in pk.decode_alarm_history(wire)] == ["ABC"]


@pytest.mark.parametrize("payload", ["", "01", "0100", "0100ea07", "ff7f" + "00" * 21])
def test_history_decoder_never_raises_on_short_payloads(payload: str) -> None:
    assert pk.decode_alarm_history(h(payload)) == []


def test_history_non_ascii_message_bytes_do_not_raise() -> None:
    wire = h("0100") + entry_bytes(2026, 1, 1, 0, 0, 0, 0, 1, 9, b"\xff\xfeA\x00")
    (entry,) = pk.decode_alarm_history(wire)
    assert entry.message.endswith("A\x00") and len(entry.message) == 4


def test_history_error_response_is_a_negative_count() -> None:
    assert pk.encode_alarm_history_error(6) == struct.pack("<h", -6)
    assert pk.decode_alarm_history(pk.encode_alarm_history_error(6)) == []


# ---- ODBALMHIS errors at the client: the status the seed's empty list hides (issue 24) ----------------------
@pytest.mark.parametrize(("status", "num_alm"), [(1, -1), (6, -6), (17, -17), (21, -21), (-1, -1001),
                                                 (-8, -1008), (-16, -1016), (-17, -1017)])
def test_history_error_status_travels_in_num_alm_both_signs_apart(status: int, num_alm: int) -> None:
    wire = pk.encode_alarm_history_error(status)
    assert wire == struct.pack("<h", num_alm)
    assert pk.alarm_history_status(num_alm) == status
    assert pk.decode_alarm_history(wire) == []  # the seed's rule holds for every one of them
    assert pk.parse_alarm_history(wire) == pk.AlarmHistoryAnswer([], status, num_alm)


@pytest.mark.parametrize(("num_alm", "kind", "code"), [
    (-16, CncError, 16),  # a foreign server's -16: the CNC's code 16 (-status, as the seed's surface says)
    (-1016, CncError, -16),  # ours: EW_SOCKET, the library host's "CNC unavailable" (a call that hung)
    (-1, FunctionNotAvailable, 1),
    (-1001, CncError, -1),
    (-3, OutOfRange, 3),
    (-11, AccessDenied, 17),
    (-32768, CncError, -31768),
])
def test_history_negative_num_alm_raises_its_error_at_the_client(num_alm: int, kind: type[CncError],
                                                                 code: int) -> None:
    wire = struct.pack("<h", num_alm) + entry_bytes(2026, 1, 1, 0, 0, 0, 0, 1, 2, b"X")
    with pytest.raises(kind) as caught:
        pk.decode_alarm_history_response(wire)
    assert caught.value.code == code and caught.value.function == "cnc_rdalmhistry"


@pytest.mark.parametrize("payload", ["", "01", "0100", "0300" + "00" * 20, "0100ea07"])
def test_history_answer_shorter_than_its_num_alm_is_a_protocol_error_at_the_client(payload: str) -> None:
    assert pk.parse_alarm_history(h(payload)).truncated
    with pytest.raises(ProtocolError, match="cnc_rdalmhistry"):
        pk.decode_alarm_history_response(h(payload))


def test_history_client_decoder_keeps_the_seeds_entries_and_bad_date_rule() -> None:
    wire = (h("0300") + entry_bytes(2026, 3, 1, 8, 0, 0, 1, 2, 100, b"FIRST")
            + entry_bytes(2026, 13, 1, 0, 0, 0, 0, 2, 200, b"BAD")
            + entry_bytes(2026, 3, 1, 6, 0, 0, 0, 3, 300, b"THIRD"))
    assert pk.decode_alarm_history_response(wire) == pk.decode_alarm_history(wire)
    assert pk.parse_alarm_history(wire).skipped == 1
    assert pk.decode_alarm_history_response(h("0000")) == []


# ---- IODBPSD (0x0102 write, 0x0002/0x0004 read) ---------------------------------------------------------
@pytest.mark.parametrize(
    ("ptype", "value", "wire"),
    [
        (ParamType.BYTE, 5, "1707" "0100" "05"),  # byte: 4 + 1
        (ParamType.BYTE, -1, "1707" "0100" "ff"),  # one signed byte
        (ParamType.BIT, 0b1011_0000, "1707" "0100" "b0"),
        (ParamType.WORD, 3000, "1707" "0100" "b80b"),  # int16: 4 + 2
        (ParamType.WORD, -2, "1707" "0100" "feff"),
        (ParamType.TWO_WORD, 500000, "1707" "0100" "20a10700"),  # int32: 4 + 4
        (ParamType.TWO_WORD, -35, "1707" "0100" "ddffffff"),
        (ParamType.REAL, 12.5, "1707" "0100" "7d000000" "01000000"),  # REALPRM extension: 4 + 8
    ],
)
def test_param_write_layout(ptype: ParamType, value: int | float, wire: str) -> None:
    payload = pk.encode_param_write(1815, 1, ptype, value)
    assert payload == h(wire)
    request = pk.decode_param_write(payload)
    assert (request.number, request.axis) == (1815, 1)
    assert request.value_as(ptype) == value


def test_param_write_whole_cnc_is_type_0() -> None:
    assert pk.encode_param_write(6711, 0, ParamType.TWO_WORD, 7) == h("371a" "0000" "07000000")


def test_param_byte_reads_back_signed_and_bit_unsigned() -> None:
    assert pk.decode_param_value(ParamType.BYTE, h("80")) == -128
    assert pk.decode_param_value(ParamType.BIT, h("80")) == 128


@pytest.mark.parametrize(
    ("ptype", "value"),
    [(ParamType.BYTE, 256), (ParamType.BYTE, -129), (ParamType.WORD, 70000), (ParamType.TWO_WORD, 2**32),
     (ParamType.WORD, 1.5), (ParamType.REAL, float("nan"))],
)
def test_param_value_that_does_not_fit_is_refused_before_sending(ptype: ParamType, value: float) -> None:
    with pytest.raises(OutOfRange):
        pk.encode_param_write(1, 0, ptype, value)


@pytest.mark.parametrize("length", [0, 3, 4, 7, 9, 10, 13])
def test_param_write_of_impossible_length_is_a_protocol_error(length: int) -> None:
    with pytest.raises(ProtocolError, match="IODBPSD"):
        pk.decode_param_write(bytes(length))


def test_param_read_request_and_response() -> None:
    assert pk.encode_param_read(6711, 0) == h("371a0000")
    assert pk.decode_param_read(h("1707ffff")) == (1815, -1)
    record = ParamRecord(1815, -1, ParamType.BIT, (0x30, 0x31, 0x30))
    response = pk.read_response(pk.encode_param_record(record))
    assert response == h("0000" "0000" "1707" "ffff" "303130")  # status, type, IODBPSD, 3 slots
    assert pk.decode_param_response(response) == record


def test_param_read_error_status_raises_typed_error() -> None:
    with pytest.raises(OutOfRange) as info:
        pk.decode_param_response(h("0300"))
    assert info.value.function == "cnc_rdparam"
    with pytest.raises(OutOfRange) as info:
        pk.decode_param_response(h("0300"), pk.Command.RDDIAG)
    assert info.value.function == "cnc_rddiag"


@pytest.mark.parametrize("body", ["0000", "0000171a0000", "0700" "171a0000" "01", "0200" "171a0000" "010203"])
def test_param_read_malformed_body_is_a_protocol_error(body: str) -> None:
    with pytest.raises(ProtocolError):
        pk.decode_param_response(h("0000" + body))


# ---- ODBM (0x0103 write, 0x0003 read) ----------------------------------------------------------------------
def test_macro_write_layout_fractional() -> None:
    # number 500, length 8, mcr_val 12345, dec_val 3
    assert pk.encode_macro(500, 12.345) == h("f401" "0800" "39300000" "0300")


def test_macro_write_layout_integer_and_negative() -> None:
    assert pk.encode_macro(100, 7) == h("6400" "0800" "07000000" "0000")
    assert pk.encode_macro(503, -0.125) == h("f701" "0800" "83ffffff" "0300")


def test_macro_read_applies_mcr_val_over_ten_to_dec_val() -> None:
    assert pk.decode_macro(h("f401" "0800" "39300000" "0300")) == (500, 12.345)
    assert pk.decode_macro(h("f401" "0800" "39300000" "0000")) == (500, 12345.0)
    assert pk.decode_macro(h("f401" "0800" "39300000" "0500")) == (500, 0.12345)


def test_macro_vacant_is_dec_val_minus_one() -> None:
    assert pk.encode_macro(501, None) == h("f501" "0800" "00000000" "ffff")
    assert pk.decode_macro(pk.encode_macro(501, None)) == (501, None)


def test_macro_length_field_must_be_8() -> None:
    with pytest.raises(ProtocolError, match="length field 8"):
        pk.decode_macro(h("f401" "0a00" "39300000" "0300"))


def test_macro_read_request_and_response() -> None:
    assert pk.encode_macro_read(500) == h("f401")
    assert pk.decode_macro_read(h("f401")) == 500
    assert pk.decode_macro_response(h("0000") + pk.encode_macro(500, 12.345)) == (500, 12.345)
    with pytest.raises(OutOfRange):
        pk.decode_macro_response(h("0300"))


@pytest.mark.parametrize(
    ("value", "scaled"),
    [(12.345, (12345, 3)), (0.0, (0, 0)), (3, (3, 0)), (-0.125, (-125, 3)), (1e-9, (1, 9)),
     (2147483647, (2147483647, 0)), (0.1 + 0.2, (300000000, 9)), (123456.789012, (1234567890, 4))],
)
def test_scaled_integer_encoding(value: float, scaled: tuple[int, int]) -> None:
    assert pk.to_scaled(value) == scaled


@pytest.mark.parametrize("value", [2**31, -(2**31) - 1, 1e10, float("inf"), float("nan"), True])
def test_scaled_integer_refuses_what_does_not_fit(value: float) -> None:
    with pytest.raises(OutOfRange):
        pk.to_scaled(value)


# ---- IODBPMC (0x0104 write, 0x4002 read) -----------------------------------------------------------------
def test_pmc_letter_codes_are_the_seeds() -> None:
    assert pk.PMC_TYPE_A == {"R": 5, "G": 4, "F": 3, "D": 8, "X": 1, "Y": 2, "K": 10, "A": 11, "E": 12,
                             "T": 6, "C": 7}


def test_pmc_write_layout() -> None:
    # type_a R=5, type_d 0, datano_s 100, datano_e 103, then exactly 4 data bytes
    assert pk.encode_pmc_write("R", 100, b"FOCS") == h("0500" "0000" "6400" "6700" "464f4353")
    assert pk.encode_pmc_write("g", 8, b"\x10") == h("0400" "0000" "0800" "0800" "10")


def test_pmc_write_addresses_are_unsigned() -> None:
    payload = pk.encode_pmc_write("D", 40000, b"\x01\x02")
    assert payload == h("0800" "0000" "409c" "419c" "0102")
    assert pk.decode_pmc_range(payload, True) == pk.PmcRange("D", 0, 40000, 40001, b"\x01\x02")


def test_pmc_write_over_32_bytes_is_refused() -> None:
    assert len(pk.encode_pmc_write("R", 0, bytes(32))) == 40  # 8-byte header + 32 bytes: the ceiling
    with pytest.raises(LengthError):
        pk.encode_pmc_write("R", 0, bytes(33))
    with pytest.raises(LengthError):
        pk.encode_pmc_write("R", 0, b"")


def test_pmc_area_without_a_code_is_refused() -> None:
    with pytest.raises(OutOfRange, match="no packed type_a"):
        pk.encode_pmc_write("M", 0, b"\x00")


@pytest.mark.parametrize(
    ("payload", "message"),
    [("0500000064006700" "464f43", "exactly 4 data bytes"),
     ("0500000064006700" "464f435300", "exactly 4 data bytes"),
     ("0500000067006400" "46", "before datano_s"),
     ("05000000640064", "8-byte IODBPMC header")],
)
def test_pmc_write_malformed(payload: str, message: str) -> None:
    with pytest.raises(ProtocolError, match=message):
        pk.decode_pmc_range(h(payload), True)


def test_pmc_unknown_type_a_is_its_own_error() -> None:
    with pytest.raises(pk.PmcCodeError, match="type_a 9"):
        pk.decode_pmc_range(h("0900" "0000" "0000" "0000" "00"), True)


def test_pmc_read_request_and_response() -> None:
    assert pk.encode_pmc_read("D", 2204, 2205, PmcType.WORD) == h("0800" "0100" "9c08" "9d08")
    response = h("0000") + h("0800" "0100" "9c08" "9d08" "5802")  # word 600, little-endian
    rng = pk.decode_pmc_read_response(response)
    assert pk.pmc_values(rng.data_type, rng.data) == [600]


@pytest.mark.parametrize(
    ("data_type", "data", "values"),
    [(PmcType.BYTE, "00ff80", [0, 255, 128]), (PmcType.WORD, "ffff0100", [-1, 1]),
     (PmcType.LONG, "feffffff", [-2]), (PmcType.FLOAT, "0000c03f", [1.5]),
     (PmcType.DOUBLE, "000000000000f83f", [1.5])],
)
def test_pmc_values_little_endian(data_type: PmcType, data: str, values: list[float]) -> None:
    assert pk.pmc_values(data_type, h(data)) == values


def test_pmc_values_partial_element_is_a_protocol_error() -> None:
    with pytest.raises(ProtocolError, match="whole number"):
        pk.pmc_values(PmcType.LONG, h("000000"))


# ---- ODBST (0x0001) ---------------------------------------------------------------------------------------
def test_cncstat_is_nine_int16_in_fwlib_order() -> None:
    status = pk.CncStatus(hdck=0, tmmode=0, aut=1, run=3, motion=1, mstb=0, emergency=0, alarm=1, edit=0)
    assert pk.encode_cncstat(status) == h("0000" "0000" "0100" "0300" "0100" "0000" "0000" "0100" "0000")
    response = pk.read_response(pk.encode_cncstat(status))
    assert pk.decode_cncstat_response(response) == status
    assert status.to_statinfo() == StatInfo(1, 3, 1, 0, 0, 1, 0)
    assert pk.CncStatus.from_statinfo(StatInfo(1, 3, 1, 0, 0, 1, 0)) == status


def test_cncstat_wrong_size_is_a_protocol_error() -> None:
    with pytest.raises(ProtocolError, match="ODBST: expected 18 bytes"):
        pk.decode_cncstat_response(h("0000") + bytes(14))


# ---- extensions ------------------------------------------------------------------------------------------
def test_sysinfo_layout() -> None:
    info = SysInfo(addinfo=0x0202, max_axis=32, cnc_type="31", mt_type=" M", series="G421", version="08.0",
                   axes="05")
    body = pk.encode_sysinfo(info)
    assert body == h("0202" "2000") + b"31 MG42108.005"
    assert pk.decode_sysinfo_response(pk.read_response(body)) == info


def test_clock_layout() -> None:
    when = datetime(2026, 3, 29, 2, 30, 15)
    assert pk.encode_clock(when) == h("ea07" "0300" "1d00" "0200" "1e00" "0f00")
    assert pk.decode_clock_response(pk.read_response(pk.encode_clock(when))) == when
    with pytest.raises(ProtocolError, match="impossible date"):
        pk.decode_clock_response(h("0000" "ea07" "0000" "0100" "0000" "0000" "0000"))


def test_active_alarms_layout() -> None:
    alarms = [ActiveAlarm(500, 4, 1, "OVER TRAVEL"), ActiveAlarm(1004, 15, 0, "")]
    body = pk.encode_alarm_messages(alarms)
    assert body[:2] == h("0200")
    assert body[2:12] == h("f4010000" "0400" "0100" "0b00")  # i32 alm_no, type, axis, msg_len 11
    assert len(body) == 2 + 24 + 12  # (10 + 11 + 3) and (10 + 0 + 2): blocks padded to 4
    assert pk.decode_alarm_messages_response(pk.read_response(body)) == alarms


def test_active_alarms_overrun_is_a_protocol_error() -> None:
    with pytest.raises(ProtocolError, match="runs past"):
        pk.decode_alarm_messages_response(h("0000" "0100" "f4010000" "0400" "0100" "2000" "41"))


def test_small_reads_round_trip() -> None:
    assert pk.decode_program_numbers_response(
        pk.read_response(pk.encode_program_numbers(ProgramNumbers(1234, 1000)))) == ProgramNumbers(1234, 1000)
    assert pk.encode_program_numbers(ProgramNumbers(1234, 1000)) == h("d2040000" "e8030000")
    timer = TimerValue(90, 500)
    assert pk.decode_timer_response(pk.read_response(pk.encode_timer(timer))) == timer
    assert pk.decode_int32_response(pk.read_response(pk.encode_int32(-7)), pk.Command.ALARM) == -7
    assert pk.decode_float_response(pk.read_response(pk.encode_float(1200.5)), pk.Command.ACTF) == 1200.5
    assert pk.decode_float_response(pk.read_response(pk.encode_float(None)), pk.Command.ACTS) is None
    values = [1.5, None, -3.25]
    positions = pk.read_response(pk.encode_floats(values))
    assert pk.decode_floats_response(positions, pk.Command.POSITION) == values
    assert pk.encode_axis_names(["X", "Y2"]) == h("0200") + b"X\x00\x00\x00Y2\x00\x00"
    assert pk.decode_axis_names_response(pk.read_response(pk.encode_axis_names(["X", "Y2"]))) == ["X", "Y2"]


def test_read_with_error_status_raises_and_short_payload_is_protocol_error() -> None:
    with pytest.raises(FunctionNotAvailable):
        pk.decode_sysinfo_response(h("0100"))
    with pytest.raises(ProtocolError, match="2-byte status"):
        pk.decode_clock_response(h("00"))
    with pytest.raises(ProtocolError):
        pk.decode_floats_response(h("0000" "0300") + bytes(16), pk.Command.POSITION)
