"""The packed surface's IPC framing: u32 length | u16 command | u16 seq | payload, little-endian."""

from __future__ import annotations

import pytest

from edge.focas.errors import ProtocolError
from edge.focas.packed.frame import MAX_LENGTH, FrameDecoder, PackedFrame


def test_frame_layout() -> None:
    frame = PackedFrame(command=0x0F1A, seq=7, payload=bytes.fromhex("6400"))
    assert frame.encode() == bytes.fromhex("06000000" "1a0f" "0700" "6400")


def test_empty_payload_frame_is_eight_bytes() -> None:
    assert PackedFrame(0x4001, 0xFFFF).encode() == bytes.fromhex("04000000" "0140" "ffff")


def test_decoder_returns_frames_in_order_from_one_chunk() -> None:
    frames = [PackedFrame(1, 1, b""), PackedFrame(0x0104, 2, bytes(40)), PackedFrame(3, 3, b"\x01\x02")]
    wire = b"".join(f.encode() for f in frames)
    decoder = FrameDecoder()
    assert decoder.feed(wire) == frames
    assert decoder.buffered == 0


def test_decoder_one_byte_at_a_time_decodes_identically() -> None:
    frames = [PackedFrame(0x0103, n, bytes(range(n))) for n in range(12)]
    wire = b"".join(f.encode() for f in frames)
    decoder = FrameDecoder()
    got: list[PackedFrame] = []
    for i in range(len(wire)):
        got.extend(decoder.feed(wire[i : i + 1]))
    assert got == frames


def test_partial_frame_waits_for_the_rest() -> None:
    wire = PackedFrame(2, 9, b"abcdef").encode()
    decoder = FrameDecoder()
    assert decoder.feed(wire[:9]) == []
    assert decoder.buffered == 9
    assert decoder.feed(wire[9:]) == [PackedFrame(2, 9, b"abcdef")]


@pytest.mark.parametrize("length", [0, 1, 3])
def test_length_below_the_header_is_a_protocol_error(length: int) -> None:
    with pytest.raises(ProtocolError, match=r"expected a length of 4\.\."):
        FrameDecoder().feed(length.to_bytes(4, "little") + bytes(8))


def test_length_above_the_bound_is_a_protocol_error() -> None:
    decoder = FrameDecoder(max_length=100)
    with pytest.raises(ProtocolError, match=r"4\.\.100, got 101"):
        decoder.feed((101).to_bytes(4, "little"))


def test_native_focas_bytes_are_rejected_by_length() -> None:
    with pytest.raises(ProtocolError, match="a0 a0 a0 a0"):
        FrameDecoder().feed(bytes.fromhex("a0a0a0a000010101000200 02"))


def test_a_failed_decoder_stays_failed() -> None:
    decoder = FrameDecoder()
    with pytest.raises(ProtocolError):
        decoder.feed(b"\xff\xff\xff\xff")
    with pytest.raises(ProtocolError, match="already failed"):
        decoder.feed(PackedFrame(1, 1).encode())


def test_encoder_refuses_oversized_payload_and_out_of_range_ids() -> None:
    with pytest.raises(ProtocolError, match="exceeds"):
        PackedFrame(1, 1, bytes(MAX_LENGTH)).encode()
    with pytest.raises(ProtocolError, match="u16"):
        PackedFrame(0x10000, 1).encode()
    with pytest.raises(ProtocolError, match="u16"):
        PackedFrame(1, -1).encode()


def test_largest_allowed_frame_round_trips() -> None:
    frame = PackedFrame(0x4002, 1, bytes(MAX_LENGTH - 4))
    assert FrameDecoder().feed(frame.encode()) == [frame]


def test_decoder_bound_must_hold_a_header() -> None:
    with pytest.raises(ValueError):
        FrameDecoder(max_length=3)
