"""Property tests of the packed surface: decoders on arbitrary bytes, encoder/decoder inverses."""

from __future__ import annotations

import contextlib
import struct
import time
from datetime import UTC, datetime

from hypothesis import given
from hypothesis import strategies as st

from edge.focas import packed as pk
from edge.focas.errors import CncError, ProtocolError
from edge.focas.model import AlarmHistoryEntry, ParamRecord, ParamType
from edge.focas.packed.frame import MAX_LENGTH, FrameDecoder, PackedFrame

ascii_text = st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=40)
utc_times = st.datetimes(min_value=datetime(1, 1, 1), max_value=datetime(9999, 12, 31)).map(
    lambda d: d.replace(microsecond=0, tzinfo=UTC)
)
int16 = st.integers(-(2**15), 2**15 - 1)
history_entries = st.builds(AlarmHistoryEntry, occurred=utc_times, axis_no=int16, alm_type=int16,
                            alm_no=int16, message=ascii_text)


# ---- ODBALMHIS -------------------------------------------------------------------------------------------
@given(st.binary(max_size=600))
def test_property_history_decoder_never_raises(payload: bytes) -> None:
    entries = pk.decode_alarm_history(payload)
    assert all(e.occurred.tzinfo is UTC for e in entries)


@given(st.lists(history_entries, max_size=12), st.data())
def test_property_history_decoder_never_raises_on_mutated_payloads(entries: list[AlarmHistoryEntry],
                                                                   data: st.DataObject) -> None:
    wire = bytearray(pk.encode_alarm_history(entries))
    for _ in range(data.draw(st.integers(1, 6))):
        at = data.draw(st.integers(0, len(wire) - 1))
        wire[at] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(wire)))
    assert len(pk.decode_alarm_history(bytes(wire[:cut]))) <= max(0, struct.unpack_from("<h", wire)[0])


@given(st.lists(history_entries, max_size=20))
def test_property_history_decode_inverts_encode(entries: list[AlarmHistoryEntry]) -> None:
    assert pk.decode_alarm_history(pk.encode_alarm_history(entries)) == entries


@given(st.lists(history_entries, max_size=20))
def test_property_history_encode_inverts_decode(entries: list[AlarmHistoryEntry]) -> None:
    wire = pk.encode_alarm_history(entries)
    assert pk.encode_alarm_history(pk.decode_alarm_history(wire)) == wire


@given(st.lists(history_entries, min_size=1, max_size=8), st.data())
def test_property_history_truncated_payload_keeps_a_prefix(entries: list[AlarmHistoryEntry],
                                                           data: st.DataObject) -> None:
    wire = pk.encode_alarm_history(entries)
    cut = data.draw(st.integers(0, len(wire) - 1))
    decoded = pk.decode_alarm_history(wire[:cut])
    assert decoded == entries[: len(decoded)]


@given(st.binary(max_size=600))
def test_property_history_client_decoder_is_the_seeds_list_or_says_why_not(payload: bytes) -> None:
    try:
        entries = pk.decode_alarm_history_response(payload)
    except (ProtocolError, CncError):
        answer = pk.parse_alarm_history(payload)
        assert answer.status or answer.truncated
    else:
        assert entries == pk.decode_alarm_history(payload)


@given(st.lists(history_entries, min_size=1, max_size=8), st.data())
def test_property_history_client_decoder_never_hands_on_a_cut_list(entries: list[AlarmHistoryEntry],
                                                                   data: st.DataObject) -> None:
    wire = pk.encode_alarm_history(entries)
    cut = data.draw(st.integers(0, len(wire) - 1))
    try:
        decoded = pk.decode_alarm_history_response(wire[:cut])
    except ProtocolError:
        return
    assert decoded == entries  # only a cut inside the last entry's padding leaves every entry whole


# ---- framing ---------------------------------------------------------------------------------------------
@given(st.lists(st.binary(max_size=64), max_size=20))
def test_property_frame_decoder_only_raises_protocol_error(chunks: list[bytes]) -> None:
    decoder = FrameDecoder(max_length=4096)
    started = time.monotonic()
    try:
        for chunk in chunks:
            for frame in decoder.feed(chunk):
                assert len(frame.payload) <= 4096 - 4
    except ProtocolError:
        pass
    assert time.monotonic() - started < 1.0


frames = st.builds(PackedFrame, command=st.integers(0, 0xFFFF), seq=st.integers(0, 0xFFFF),
                   payload=st.binary(max_size=300))


@given(st.lists(frames, max_size=10), st.data())
def test_property_frames_survive_any_split(sent: list[PackedFrame], data: st.DataObject) -> None:
    wire = b"".join(f.encode() for f in sent)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(wire)), max_size=12)))
    decoder = FrameDecoder()
    got: list[PackedFrame] = []
    previous = 0
    for cut in [*cuts, len(wire)]:
        got.extend(decoder.feed(wire[previous:cut]))
        previous = cut
    assert got == sent
    assert decoder.buffered == 0


@given(st.binary(min_size=4, max_size=4))
def test_property_any_length_prefix_is_accepted_or_refused_cleanly(prefix: bytes) -> None:
    length = int.from_bytes(prefix, "little")
    decoder = FrameDecoder()
    try:
        assert decoder.feed(prefix) == []
        assert 4 <= length <= MAX_LENGTH
    except ProtocolError:
        assert not 4 <= length <= MAX_LENGTH


# ---- other decoders: only ProtocolError or a typed CNC error ------------------------------------------
RESPONSE_DECODERS = [
    pk.decode_cncstat_response,
    pk.decode_param_response,
    pk.decode_macro_response,
    pk.decode_pmc_read_response,
    pk.decode_sysinfo_response,
    pk.decode_clock_response,
    pk.decode_alarm_messages_response,
    pk.decode_program_numbers_response,
    pk.decode_timer_response,
    pk.decode_axis_names_response,
    lambda p: pk.decode_int32_response(p, pk.Command.ALARM),
    lambda p: pk.decode_float_response(p, pk.Command.ACTF),
    lambda p: pk.decode_floats_response(p, pk.Command.POSITION),
    lambda p: pk.decode_status(p, pk.Command.WRPARAM),
    pk.decode_alarm_history_response,
]
REQUEST_DECODERS = [
    pk.decode_param_write,
    pk.decode_param_read,
    pk.decode_macro_read,
    lambda p: pk.decode_macro(p, "cnc_wrmacro"),
    lambda p: pk.decode_pmc_range(p, True),
    lambda p: pk.decode_pmc_range(p, False),
    pk.decode_alarm_history_request,
]


@given(st.sampled_from(RESPONSE_DECODERS + REQUEST_DECODERS), st.binary(max_size=80))
def test_property_decoders_raise_only_protocol_or_cnc_errors(decode: object, payload: bytes) -> None:
    assert callable(decode)
    with contextlib.suppress(ProtocolError, CncError):
        decode(payload)


@given(st.sampled_from(RESPONSE_DECODERS), st.binary(max_size=80))
def test_property_decoders_on_status_zero_bodies(decode: object, body: bytes) -> None:
    assert callable(decode)
    with contextlib.suppress(ProtocolError, CncError):
        decode(b"\x00\x00" + body)


# ---- inverses of the write encoders ---------------------------------------------------------------------
PARAM_VALUES = {
    ParamType.BIT: st.integers(0, 255),
    ParamType.BYTE: st.integers(-128, 127),
    ParamType.WORD: st.integers(-(2**15), 2**15 - 1),
    ParamType.TWO_WORD: st.integers(-(2**31), 2**31 - 1),
    ParamType.REAL: st.builds(lambda m, d: m / 10**d, st.integers(-(2**31), 2**31 - 1), st.integers(0, 9)),
}


@given(st.sampled_from(list(ParamType)), st.data(), int16, int16)
def test_property_param_write_round_trip(ptype: ParamType, data: st.DataObject, number: int,
                                         axis: int) -> None:
    value = data.draw(PARAM_VALUES[ptype])
    request = pk.decode_param_write(pk.encode_param_write(number, axis, ptype, value))
    assert (request.number, request.axis, request.value_as(ptype)) == (number, axis, value)


@given(st.sampled_from(list(ParamType)), st.data(), int16, st.integers(-1, 8))
def test_property_param_record_round_trip(ptype: ParamType, data: st.DataObject, number: int,
                                          axis: int) -> None:
    values = tuple(data.draw(st.lists(PARAM_VALUES[ptype], min_size=1, max_size=8)))
    record = ParamRecord(number, axis, int(ptype), values)
    assert pk.decode_param_response(pk.read_response(pk.encode_param_record(record))) == record


@given(int16, st.integers(-(2**31), 2**31 - 1), st.integers(0, 9))
def test_property_macro_round_trip(number: int, mantissa: int, decimals: int) -> None:
    value = mantissa / 10**decimals
    assert pk.decode_macro(pk.encode_macro(number, value)) == (number, value)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-2e9, max_value=2e9))
def test_property_scaled_value_is_close(value: float) -> None:
    mantissa, decimals = pk.to_scaled(value)
    assert -(2**31) <= mantissa < 2**31
    assert abs(pk.from_scaled(mantissa, decimals) - value) <= max(abs(value) * 1e-9, 10.0**-decimals)


@given(st.sampled_from(sorted(pk.PMC_TYPE_A)), st.integers(0, 0xFFFF - 32),
       st.binary(min_size=1, max_size=32))
def test_property_pmc_write_round_trip(area: str, start: int, data: bytes) -> None:
    rng = pk.decode_pmc_range(pk.encode_pmc_write(area, start, data), True)
    assert (rng.area, rng.data_type, rng.start, rng.end, rng.data) == (area, 0, start, start + len(data) - 1,
                                                                       data)


@given(st.integers(-(2**15), 2**15 - 1))
def test_property_history_request_is_always_in_range(depth: int) -> None:
    (wire,) = struct.unpack("<h", pk.encode_alarm_history_request(depth))
    assert wire == min(250, max(1, depth))
