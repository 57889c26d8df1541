"""Property tests on the framer: any split decodes the same, and any bytes at all only ever give frames
or a ProtocolError, quickly."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.focas.errors import ProtocolError
from edge.focas.frame import (
    Answer,
    AnswerMemo,
    AnswerSplitter,
    FrameDecoder,
    RequestSubpacket,
    ResponseSubpacket,
    decode_request_body,
    decode_response_body,
    encode_request,
    encode_response,
    split_response,
)
from edge.focas.function_entry import Context
from edge.focas.functions import BY_COMMAND
from edge.focas.values import SlotForm

u16 = st.integers(0, 0xFFFF)
i16 = st.integers(-(2**15), 2**15 - 1)
i32 = st.integers(-(2**31), 2**31 - 1)

request_subpackets = st.builds(
    RequestSubpacket, u16, u16, st.tuples(i32, i32, i32, i32, i32), st.binary(max_size=40), u16)
response_subpackets = st.builds(ResponseSubpacket, u16, u16, i16, i16, st.binary(max_size=60), u16)
responses = st.builds(lambda subs, version: encode_response(subs, version),
                      st.lists(response_subpackets, max_size=6), st.integers(1, 4))

TIME_BOUND = 1.0  # seconds for one decode of at most a few KB; generous for slow CI


def _decode_everything(data: bytes, chunk: int = 0) -> list[Any]:
    """Frames and their bodies as far as they go; ProtocolError is the only allowed failure."""
    decoder = FrameDecoder()
    out: list[Any] = []
    pieces = [data] if chunk <= 0 else [data[i : i + chunk] for i in range(0, len(data), chunk)]
    for piece in pieces:
        for frame in decoder.feed(piece):
            out.append(frame)
            if frame.type == 0x2102:
                subs = decode_response_body(frame.body)
                out.append(subs)
                for sub in subs:
                    function = BY_COMMAND.get((sub.cls, sub.command))
                    if function is not None and sub.rc == 0:
                        req = function.request(1, 2, 1, 1)
                        out.append(function.decode_payload(sub.payload, req,
                                                           Context(4, SlotForm.SCALED)))
            elif frame.type == 0x2101:
                out.append(decode_request_body(frame.body))
    return out


@given(st.lists(request_subpackets, max_size=6))
def test_request_round_trip(subs: list[RequestSubpacket]) -> None:
    (frame,) = FrameDecoder().feed(encode_request(subs))
    assert decode_request_body(frame.body) == subs


@given(st.lists(response_subpackets, max_size=6), st.integers(1, 4))
def test_response_round_trip(subs: list[ResponseSubpacket], version: int) -> None:
    (frame,) = FrameDecoder().feed(encode_response(subs, version))
    assert frame.version == version
    assert decode_response_body(frame.body) == subs


@given(st.lists(responses, min_size=1, max_size=4), st.integers(1, 50))
def test_any_split_decodes_identically(frames: list[bytes], chunk: int) -> None:
    stream = b"".join(frames)
    whole = FrameDecoder().feed(stream)
    decoder = FrameDecoder()
    split = [f for i in range(0, len(stream), chunk) for f in decoder.feed(stream[i : i + chunk])]
    assert split == whole and len(whole) == len(frames)
    byte_wise = FrameDecoder()
    assert [f for b in stream for f in byte_wise.feed(bytes([b]))] == whole


@given(st.binary(max_size=2000), st.integers(0, 64))
def test_random_bytes_only_raise_protocol_error(data: bytes, chunk: int) -> None:
    started = time.monotonic()
    with contextlib.suppress(ProtocolError):
        _decode_everything(data, chunk)
    assert time.monotonic() - started < TIME_BOUND


@st.composite
def mutated_frames(draw: st.DrawFn) -> bytes:
    """A valid response with a few bytes flipped, inserted or cut: the shape garbage usually has."""
    data = bytearray(draw(responses))
    for _ in range(draw(st.integers(1, 4))):
        action = draw(st.sampled_from(["flip", "insert", "delete", "truncate"]))
        position = draw(st.integers(0, max(0, len(data) - 1)))
        if action == "flip" and data:
            data[position] ^= draw(st.integers(1, 255))
        elif action == "insert":
            data[position:position] = draw(st.binary(min_size=1, max_size=4))
        elif action == "delete" and data:
            del data[position]
        elif action == "truncate":
            del data[position:]
    return bytes(data)


@given(mutated_frames(), st.integers(0, 16))
def test_mutated_frames_only_raise_protocol_error(data: bytes, chunk: int) -> None:
    started = time.monotonic()
    with contextlib.suppress(ProtocolError):
        _decode_everything(data, chunk)
    assert time.monotonic() - started < TIME_BOUND


@given(st.integers(0, 0xFFFF), st.binary(max_size=100))
def test_header_with_any_length_never_overbuffers(length: int, tail: bytes) -> None:
    decoder = FrameDecoder(max_body=1024)
    header = b"\xa0\xa0\xa0\xa0\x00\x02\x21\x02" + length.to_bytes(2, "big")
    body = tail[:length]
    try:
        frames = decoder.feed(header + body)
    except ProtocolError:
        assert length > 1024
    else:
        assert length <= 1024
        assert decoder.buffered == (0 if frames else 10 + len(body))
        assert len(frames) == (1 if len(body) == length else 0)


@given(st.lists(response_subpackets, max_size=8))
def test_property_split_response_agrees_with_decode_response_body(subs: list[ResponseSubpacket]) -> None:
    body = encode_response(subs)[10:]
    echoes = [(sub.cls, sub.path, sub.command) for sub in subs]
    assert split_response(body, echoes) == [(s.rc, s.detail, s.payload) for s in decode_response_body(body)]


@given(st.lists(response_subpackets, min_size=1, max_size=4), st.data())
def test_property_split_response_rejects_a_wrong_echo_or_count(subs: list[ResponseSubpacket],
                                                                data: st.DataObject) -> None:
    body = encode_response(subs)[10:]
    echoes = [(sub.cls, sub.path, sub.command) for sub in subs]
    index = data.draw(st.integers(0, len(echoes) - 1))
    cls, path, command = echoes[index]
    wrong = [*echoes[:index], (cls, path, (command + 1) & 0xFFFF), *echoes[index + 1:]]
    with pytest.raises(ProtocolError, match="should echo"):
        split_response(body, wrong)
    with pytest.raises(ProtocolError, match="subpackets in the answer"):
        split_response(body, echoes[:-1])


@given(st.lists(response_subpackets, min_size=1, max_size=4), st.integers(1, 40))
def test_property_split_response_rejects_a_truncated_body(subs: list[ResponseSubpacket], cut: int) -> None:
    body = encode_response(subs)[10:]
    echoes = [(sub.cls, sub.path, sub.command) for sub in subs]
    with pytest.raises(ProtocolError):
        split_response(body[: max(0, len(body) - cut)], echoes)
    with pytest.raises(ProtocolError, match="left after"):
        split_response(body + b"\x00", echoes)


def _all_answers(splitter: AnswerSplitter, body: bytes, answers: Sequence[Answer | None]) -> list[Answer]:
    """What `split` gave, with the subpackets it did not parse asked for one by one."""
    return [(answers[i] if answers else None) or splitter.answer(body, i) for i in range(len(splitter._slots))]


@given(st.lists(st.tuples(u16, u16, u16), min_size=1, max_size=4, unique=True), st.data())
def test_property_answer_splitters_sharing_a_memo_answer_as_a_fresh_split(echoes: list[tuple[int, int, int]],
                                                                          data: st.DataObject) -> None:
    """Two request PDUs (tick shapes) asking overlapping subpackets, their last answers kept once in one memo;
    a run of answers to either (some subpackets repeating, some changed in content or length, some bodies
    malformed): each splitter gives what a fresh split gives, or the same error, and `moved` names exactly
    the subpackets that differ from the last answer of the same slot, whichever PDU brought it."""
    memo = AnswerMemo()
    slots = list(memo.allocate(len(echoes)))
    shapes = [list(range(len(echoes))), data.draw(st.lists(st.sampled_from(range(len(echoes))), min_size=1,
                                                            unique=True))]
    splitters = [AnswerSplitter([echoes[i] for i in shape], tuple(slots[i] for i in shape), memo)
                 for shape in shapes]
    last: dict[int, Answer] = {}  # per slot, the last answer a split accepted
    payloads = st.sampled_from([b"", b"\x00\x01", b"\x00\x02", b"\x00\x01\x00\x00"])
    for _ in range(data.draw(st.integers(1, 10))):
        which = data.draw(st.integers(0, 1))
        shape, splitter = shapes[which], splitters[which]
        subs = [ResponseSubpacket(echoes[i][0], echoes[i][2], data.draw(st.sampled_from([0, 0, 5])), 0,
                                  data.draw(payloads), echoes[i][1]) for i in shape]
        body = encode_response(subs)[10:]
        body = data.draw(st.sampled_from([body, body, body, body[:-1], body + b"\x00"]))
        try:
            expected = split_response(body, [echoes[i] for i in shape])
        except ProtocolError as exc:
            with pytest.raises(ProtocolError, match=str(exc)[:20].replace("(", ".").replace(")", ".")):
                splitter.split(body)
            continue  # the memo still holds the last good answers
        answers, moved = splitter.split(body)
        assert _all_answers(splitter, body, answers) == expected
        if moved is None:  # the splitter's first answer: every subpacket is new to its caller
            assert all(answer is not None for answer in answers)
        else:
            assert moved == [n for n, i in enumerate(shape) if last.get(i) != expected[n]]
            assert all(answers[n] == expected[n] for n in moved)
        last.update(zip(shape, expected, strict=True))


def test_answer_splitter_reparses_only_what_moved_and_notices_a_length_change() -> None:
    echoes = [(1, 1, 0x19), (1, 1, 0x24), (1, 1, 0x26)]

    def body(*payloads: bytes) -> bytes:
        return encode_response([ResponseSubpacket(c, cmd, 0, 0, p, path)
                                for (c, path, cmd), p in zip(echoes, payloads, strict=True)])[10:]

    memo = AnswerMemo()
    splitter = AnswerSplitter(echoes, tuple(memo.allocate(3)), memo)
    first, moved = splitter.split(body(b"\x00\x01", b"\x00\x02", b"\x00\x03"))
    assert moved is None and [a[2] for a in first] == [b"\x00\x01", b"\x00\x02", b"\x00\x03"]
    second, moved = splitter.split(body(b"\x00\x01", b"\x00\x09", b"\x00\x03"))
    assert moved == [1] and second[1] == (0, 0, b"\x00\x09") and second[0] is None and second[2] is None
    _, moved = splitter.split(body(b"\x00\x01", b"\x00\x09", b"\x00\x03"))
    assert moved == []
    # Same total size, but the first two subpackets trade two bytes: the layout moved, split anew; the third
    # subpacket is parsed but did not move.
    fourth, moved = splitter.split(body(b"", b"\x00\x09\x00\x00", b"\x00\x03"))
    assert moved == [0, 1] and [a[2] for a in fourth] == [b"", b"\x00\x09\x00\x00", b"\x00\x03"]
    # A string of another length among unchanged answers: only it moved.
    _, moved = splitter.split(body(b"", b"\x00\x09\x00\x00\x00\x00", b"\x00\x03"))
    assert moved == [1]
    with pytest.raises(ProtocolError, match="should echo"):
        splitter.split(encode_response([ResponseSubpacket(1, 0x99, 0, 0, b"", 1),
                                        *[ResponseSubpacket(c, cmd, 0, 0, p, path) for (c, path, cmd), p
                                          in zip(echoes[1:], (b"\x00\x09\x00\x00", b"\x00\x03"), strict=True)]])[10:])


def test_a_length_changed_by_another_pdu_is_not_taken_for_an_unchanged_answer() -> None:
    """PDU A asks slots 0 and 1, PDU B slot 0 alone. B's answer shortens slot 0; A's next answer has the same
    size as its last, slot 0 equal to what B brought and slot 1 crafted so its old bytes reappear at the old
    offset. Compared in place alone, A would find nothing moved and keep slot 1's old answer; the memo's
    generation makes A check its lengths and split anew."""
    echo = (0x14, 0x14, 0x14)
    memo = AnswerMemo()
    slot0, slot1 = memo.allocate(2)
    a = AnswerSplitter([echo, echo], (slot0, slot1), memo)
    b = AnswerSplitter([echo], (slot0,), memo)

    def sub(rc: int, detail: int, payload: bytes) -> ResponseSubpacket:
        return ResponseSubpacket(echo[0], echo[2], rc, detail, payload, echo[1])

    a.split(encode_response([sub(0, 0, b"\x00\x00\x00\x01"), sub(0, 8, b"\x00\x00\x00\x04")])[10:])
    b.split(encode_response([sub(0, 0, b"")])[10:])
    crafted = encode_response([sub(0, 0, b""), sub(0x14, 0x14, b"\x00\x00\x00\x04\x00\x00\x00\x04")])[10:]
    old_second = encode_response([sub(0, 8, b"\x00\x00\x00\x04")])[12:]
    assert crafted[22:42] == old_second and len(crafted) == 42  # the trap: old bytes at the old offset
    answers, moved = a.split(crafted)
    # Slot 0 is what B brought (its value is B's decoding of it): only slot 1 moved.
    assert moved == [1] and list(answers) == split_response(crafted, [echo, echo])
    assert answers[1] == (0x14, 0x14, b"\x00\x00\x00\x04\x00\x00\x00\x04")
