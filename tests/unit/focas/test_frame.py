"""Framing: headers, subpackets, multi-subpacket bodies and the incremental decoder."""

from __future__ import annotations

import struct

import pytest

from edge.focas.errors import ProtocolError
from edge.focas.frame import (
    Frame,
    FrameDecoder,
    PduType,
    RequestSubpacket,
    ResponseSubpacket,
    decode_frame,
    decode_request_body,
    decode_response_body,
    encode_close_response,
    encode_open_response,
    encode_request,
    encode_response,
    request_subpacket,
)

REQUESTS = [
    request_subpacket(1, 0xA4, 2),
    request_subpacket(1, 0x89),
    request_subpacket(1, 0x56, 1),
    request_subpacket(2, 0x8002, 100, 101, 5, 0, extra=b"\x01\x02"),
]
RESPONSES = [
    ResponseSubpacket(1, 0xA4, payload=b"\x00\x04"),
    ResponseSubpacket(1, 0x89, payload=b"X\x00\x00\x00Y\x00\x00\x00"),
    ResponseSubpacket(1, 0x25, rc=1),  # EW_FUNC, no payload: 16 bytes
    ResponseSubpacket(2, 0x8002),
]


def test_request_round_trip_with_several_subpackets() -> None:
    data = encode_request(REQUESTS)
    frame = decode_frame(data)
    assert (frame.version, frame.type) == (1, PduType.DATA_REQUEST)
    assert decode_request_body(frame.body) == REQUESTS
    assert REQUESTS[3].args[4] == 2  # arg5 = len(extra)


def test_response_round_trip_and_error_subpacket_is_16_bytes() -> None:
    data = encode_response(RESPONSES, version=4)
    frame = decode_frame(data)
    assert (frame.version, frame.type) == (4, PduType.DATA_RESPONSE)
    assert decode_response_body(frame.body) == RESPONSES
    assert RESPONSES[2].encode() == bytes.fromhex("0010 0001 0001 0025 0001 0000 0000 0000")


def test_published_ew_func_subpacket_decodes() -> None:
    body = struct.pack(">H", 1) + bytes.fromhex("00100001000100250001000000000000")
    (sub,) = decode_response_body(body)
    assert (sub.command, sub.rc, sub.detail, sub.payload) == (0x25, 1, 0, b"")


@pytest.mark.parametrize("version", [1, 2, 3, 4])
def test_response_versions_1_to_4_accepted(version: int) -> None:
    assert decode_frame(encode_close_response(version)).version == version


@pytest.mark.parametrize("version", [0, 5, 0x0100])
def test_other_versions_rejected(version: int) -> None:
    with pytest.raises(ProtocolError, match=rf"version in \[1, 2, 3, 4\], got {version}"):
        decode_frame(Frame(version, PduType.CLOSE_RESPONSE, b"").encode())


def test_one_byte_at_a_time_equals_all_at_once() -> None:
    stream = encode_open_response(bytes(360), 4) + encode_response(RESPONSES) + encode_close_response()
    whole = FrameDecoder().feed(stream)
    decoder = FrameDecoder()
    pieces = [frame for i in range(len(stream)) for frame in decoder.feed(stream[i : i + 1])]
    assert pieces == whole
    assert [f.type for f in whole] == [PduType.OPEN_RESPONSE, PduType.DATA_RESPONSE, PduType.CLOSE_RESPONSE]
    assert decoder.buffered == 0


def test_several_frames_in_one_read_and_a_split_tail() -> None:
    one = encode_response(RESPONSES[:1])
    decoder = FrameDecoder()
    assert len(decoder.feed(one + one + one[:7])) == 2
    assert decoder.buffered == 7
    assert len(decoder.feed(one[7:])) == 1


def test_bad_sync_fails_on_the_first_wrong_byte() -> None:
    decoder = FrameDecoder()
    with pytest.raises(ProtocolError, match="expected sync a0a0a0a0 at frame start, got a0a0"):
        decoder.feed(b"\xa0\xa0HTTP")
    with pytest.raises(ProtocolError, match="already failed"):
        decoder.feed(encode_close_response())


def test_body_limit_bounds_buffering() -> None:
    decoder = FrameDecoder(max_body=1024)
    with pytest.raises(ProtocolError, match="declares 2000 body bytes, more than the limit 1024"):
        decoder.feed(b"\xa0\xa0\xa0\xa0\x00\x02\x21\x02\x07\xd0")


@pytest.mark.parametrize("body,message", [
    (b"", "2-byte subpacket count"),
    (b"\x00\x02" + RESPONSES[0].encode(), "count says 2 subpackets but the body ends after 1"),
    (b"\x00\x01" + RESPONSES[0].encode() + b"\x00", "1 bytes left after the 1 subpackets"),
    (b"\x00\x01\x00\x05abc", "length 5 is below the minimum 16"),
    (b"\x00\x01" + RESPONSES[0].encode()[:-1], "declares 18 bytes at offset 2 but only 17 remain"),
    (b"\x00\x01" + bytes.fromhex("00120001000100240000000000000008") + b"\x00\x00",
     "announces a 8-byte payload but its length 18 leaves room for 2"),
])
def test_malformed_response_bodies(body: bytes, message: str) -> None:
    with pytest.raises(ProtocolError, match=message):
        decode_response_body(body)


def test_truncated_request_subpacket() -> None:
    body = encode_request(REQUESTS[:1])[10:]
    with pytest.raises(ProtocolError, match="below the minimum 28"):
        decode_request_body(body[:2] + b"\x00\x10" + body[4:20])


def test_decode_frame_wants_exactly_one() -> None:
    frame = encode_close_response()
    with pytest.raises(ProtocolError, match="exactly one frame"):
        decode_frame(frame + frame)
    with pytest.raises(ProtocolError, match="exactly one frame"):
        decode_frame(frame[:-1] if len(frame) > 10 else frame[:9])


def test_response_answers_request_checks_the_echo() -> None:
    req = RequestSubpacket(1, 0x15, (1, 1, 0, 0, 0))
    assert ResponseSubpacket(1, 0x15).answers(req)
    assert not ResponseSubpacket(1, 0x16).answers(req)
    assert not ResponseSubpacket(2, 0x15).answers(req)
    assert not ResponseSubpacket(1, 0x15, path=2).answers(req)


def test_encoders_refuse_what_the_fields_cannot_carry() -> None:
    with pytest.raises(ValueError):
        RequestSubpacket(1, 0x15, (2**31, 0, 0, 0, 0)).encode()
    with pytest.raises(ValueError):
        Frame(1, PduType.DATA_REQUEST, bytes(70000)).encode()
