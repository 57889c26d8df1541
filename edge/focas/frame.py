"""FOCAS/Ethernet framing, sans-IO: bytes in, frames and subpackets out (and back).

Every PDU starts with a 10-byte header::

    A0 A0 A0 A0 | version u16 | type u16 | length u16 (bytes after this field)

Data PDUs (0x2101 request, 0x2102 response) carry ``u16 count`` and then ``count`` subpackets. A request
subpacket is ``u16 len (0x1C + extra) | u16 class | u16 path | u16 command | 5 x i32 args | extra``; a
response subpacket is ``u16 len | class, path, command echo | i16 rc | i16 detail | 00 00 | u16 n | n
payload bytes`` (16 bytes when an error carries no payload). Everything is big-endian.

Both directions are encoded and decoded here, so the client and the simulated CNC share one
implementation. Malformed input raises :class:`ProtocolError` (and nothing else) with a message naming
what was expected and what arrived. See docs/protocol.md for sources and evidence.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from itertools import compress
from operator import itemgetter, ne
from typing import Any

from edge.focas.errors import ProtocolError

SYNC = b"\xa0\xa0\xa0\xa0"
HEADER_SIZE = 10
REQUEST_VERSION = 1
# Real controls answer 2 (16i/160i), 3 (31i-B) or 4 (31i); 1 is what clients send and LMX accepts back.
ACCEPTED_VERSIONS = frozenset({1, 2, 3, 4})
DEFAULT_RESPONSE_VERSION = 2
# The length field is u16, so no frame body can be longer; a decoder may be configured tighter.
MAX_BODY_LENGTH = 0xFFFF

REQUEST_SUBPACKET_FIXED = 0x1C
RESPONSE_SUBPACKET_FIXED = 16
CLASS_CNC = 1
CLASS_PMC = 2

_HEADER = struct.Struct(">4sHHH")
_REQUEST_SUB = struct.Struct(">HHHHiiiii")
RESPONSE_SUB_LAYOUT = struct.Struct(">HHHHhh2sH")
U16_LAYOUT = struct.Struct(">H")


class PduType(enum.IntEnum):
    """Header type word: high byte = kind, low byte = direction (01 to the CNC, 02 back)."""

    OPEN_REQUEST = 0x0101
    OPEN_RESPONSE = 0x0102
    CLOSE_REQUEST = 0x0201
    CLOSE_RESPONSE = 0x0202
    DATA_REQUEST = 0x2101
    DATA_RESPONSE = 0x2102


class OpenStream(enum.IntEnum):
    """Payload of the open PDU: which kind of session this TCP connection carries."""

    PROGRAM_TRANSFER = 1
    DATA = 2


@dataclass(frozen=True, slots=True)
class Frame:
    """One PDU: header fields plus the body (the bytes counted by the length field)."""

    version: int
    type: int
    body: bytes

    def encode(self) -> bytes:
        if len(self.body) > MAX_BODY_LENGTH:
            raise ValueError(f"frame body of {len(self.body)} bytes exceeds the u16 length field")
        return _HEADER.pack(SYNC, self.version, self.type, len(self.body)) + self.body


@dataclass(frozen=True, slots=True)
class RequestSubpacket:
    """One function call inside a data request: class (1 CNC, 2 PMC), command, five args, extra bytes."""

    cls: int
    command: int
    args: tuple[int, int, int, int, int] = (0, 0, 0, 0, 0)
    extra: bytes = b""
    path: int = 1

    def encode(self) -> bytes:
        length = REQUEST_SUBPACKET_FIXED + len(self.extra)
        if length > 0xFFFF:
            raise ValueError(f"subpacket extra of {len(self.extra)} bytes does not fit a u16 length")
        try:
            head = _REQUEST_SUB.pack(length, self.cls, self.path, self.command, *self.args)
        except struct.error as exc:
            raise ValueError(f"subpacket field out of range in {self!r}: {exc}") from exc
        return head + self.extra


@dataclass(frozen=True, slots=True)
class ResponseSubpacket:
    """One answer inside a data response: the echo, return code (EW_*), detail and payload."""

    cls: int
    command: int
    rc: int = 0
    detail: int = 0
    payload: bytes = b""
    path: int = 1

    def encode(self) -> bytes:
        length = RESPONSE_SUBPACKET_FIXED + len(self.payload)
        if length > 0xFFFF:
            raise ValueError(f"subpacket payload of {len(self.payload)} bytes does not fit a u16 length")
        return RESPONSE_SUB_LAYOUT.pack(length, self.cls, self.path, self.command, self.rc, self.detail,
                                  b"\x00\x00", len(self.payload)) + self.payload

    def answers(self, request: RequestSubpacket) -> bool:
        """Whether this subpacket echoes the request's class, path and command."""
        return (self.cls, self.path, self.command) == (request.cls, request.path, request.command)


def request_subpacket(cls: int, command: int, a1: int = 0, a2: int = 0, a3: int = 0, a4: int = 0,
                      a5: int | None = None, extra: bytes = b"", path: int = 1) -> RequestSubpacket:
    """A request subpacket; arg5 defaults to len(extra), as every published write does."""
    return RequestSubpacket(cls, command, (a1, a2, a3, a4, len(extra) if a5 is None else a5), extra, path)


# ---- bodies ---------------------------------------------------------------------------------------------


def encode_request_body(subpackets: Sequence[RequestSubpacket]) -> bytes:
    return U16_LAYOUT.pack(len(subpackets)) + b"".join(s.encode() for s in subpackets)


def encode_response_body(subpackets: Sequence[ResponseSubpacket]) -> bytes:
    return U16_LAYOUT.pack(len(subpackets)) + b"".join(s.encode() for s in subpackets)


def _split_subpackets(body: bytes, minimum: int, what: str) -> list[bytes]:
    """Cut a data body into subpacket byte strings (each including its own length word)."""
    if len(body) < 2:
        raise ProtocolError(f"{what}: expected a 2-byte subpacket count, got a {len(body)}-byte body")
    (count,) = U16_LAYOUT.unpack_from(body, 0)
    chunks: list[bytes] = []
    offset = 2
    for index in range(count):
        if offset + 2 > len(body):
            raise ProtocolError(f"{what}: count says {count} subpackets but the body ends after {index} "
                                f"(at byte {offset} of {len(body)})")
        (length,) = U16_LAYOUT.unpack_from(body, offset)
        if length < minimum:
            raise ProtocolError(f"{what}: subpacket {index} length {length} is below the minimum {minimum}")
        if offset + length > len(body):
            raise ProtocolError(f"{what}: subpacket {index} declares {length} bytes at offset {offset} but "
                                f"only {len(body) - offset} remain")
        chunks.append(body[offset : offset + length])
        offset += length
    if offset != len(body):
        raise ProtocolError(f"{what}: {len(body) - offset} bytes left after the {count} subpackets the "
                            f"count announced")
    return chunks


def decode_request_body(body: bytes) -> list[RequestSubpacket]:
    """The subpackets of a 0x2101 body."""
    return [decode_request_chunk(chunk) for chunk in request_chunks(body)]


def request_chunks(body: bytes) -> list[bytes]:
    """The subpacket byte strings of a 0x2101 body, each with its length word (checked as
    decode_request_body checks them); a server keys what it compiled for a request by these bytes."""
    return _split_subpackets(body, REQUEST_SUBPACKET_FIXED, "data request")


def decode_request_chunk(chunk: bytes) -> RequestSubpacket:
    """One subpacket of request_chunks."""
    _, cls, path, command, *args = _REQUEST_SUB.unpack_from(chunk, 0)
    a1, a2, a3, a4, a5 = args
    return RequestSubpacket(cls, command, (a1, a2, a3, a4, a5), bytes(chunk[REQUEST_SUBPACKET_FIXED:]), path)


def decode_response_body(body: bytes) -> list[ResponseSubpacket]:
    """The subpackets of a 0x2102 body; each payload length must match its subpacket length."""
    result = []
    for index, chunk in enumerate(_split_subpackets(body, RESPONSE_SUBPACKET_FIXED, "data response")):
        length, cls, path, command, rc, detail, _pad, size = RESPONSE_SUB_LAYOUT.unpack_from(chunk, 0)
        if size != length - RESPONSE_SUBPACKET_FIXED:
            raise ProtocolError(f"data response: subpacket {index} (command 0x{command:04x}) announces a "
                                f"{size}-byte payload but its length {length} leaves room for "
                                f"{length - RESPONSE_SUBPACKET_FIXED}")
        payload = bytes(chunk[RESPONSE_SUBPACKET_FIXED:])
        result.append(ResponseSubpacket(cls, command, rc, detail, payload, path))
    return result


Answer = tuple[int, int, bytes]  # one response subpacket reduced to (rc, detail, payload)
Echo = tuple[int, int, int]  # what a response subpacket must echo: (class, path, command)


def split_response(body: bytes, echoes: Sequence[Echo]) -> list[Answer]:
    """The answers in a 0x2102 body to requests the caller knows: one (rc, detail, payload) per request.

    The same checks as decode_response_body plus the count and every echo against `echoes`, in one pass
    and without building subpacket objects.
    """
    size = len(body)
    if size < 2:
        raise ProtocolError(f"data response: expected a 2-byte subpacket count, got a {size}-byte body")
    (count,) = U16_LAYOUT.unpack_from(body, 0)
    if count != len(echoes):
        raise ProtocolError(f"expected {len(echoes)} subpackets in the answer, got {count}")
    answers: list[Answer] = []
    offset = 2
    for index, echo in enumerate(echoes):
        if offset + RESPONSE_SUBPACKET_FIXED > size:
            raise ProtocolError(f"data response: count says {count} subpackets but the body ends after "
                                f"{index} (at byte {offset} of {size})")
        answer, length = _one_answer(body, offset, index, echo)
        answers.append(answer)
        offset += length
    if offset != size:
        raise ProtocolError(f"data response: {size - offset} bytes left after the {count} subpackets the "
                            f"count announced")
    return answers


def _one_answer(body: bytes, offset: int, index: int, echo: Echo) -> tuple[Answer, int]:
    """The subpacket at `offset` (its fixed part known to be in the body), checked; and its length."""
    length, cls, path, command, rc, detail, _pad, payload_size = RESPONSE_SUB_LAYOUT.unpack_from(body, offset)
    size = len(body)
    if length < RESPONSE_SUBPACKET_FIXED or offset + length > size:
        raise ProtocolError(f"data response: subpacket {index} declares {length} bytes at offset {offset} "
                            f"but only {size - offset} remain (minimum {RESPONSE_SUBPACKET_FIXED})")
    if payload_size != length - RESPONSE_SUBPACKET_FIXED:
        raise ProtocolError(f"data response: subpacket {index} (command 0x{command:04x}) announces a "
                            f"{payload_size}-byte payload but its length {length} leaves room for "
                            f"{length - RESPONSE_SUBPACKET_FIXED}")
    if (cls, path, command) != echo:
        raise ProtocolError(f"subpacket {index} should echo class {echo[0]} path {echo[1]} command "
                            f"0x{echo[2]:04x}, got class {cls} path {path} command 0x{command:04x}")
    return (rc, detail, body[offset + RESPONSE_SUBPACKET_FIXED : offset + length]), length


NOT_ANSWERED = b""  # a slot no answer filled yet: no subpacket is 0 bytes long, so a PDU holding it splits anew
INTERN_LIMIT = 65536  # distinct small tuples kept to share; a fleet of alike machines needs a few dozen
_INTERNED: dict[tuple[int, ...], tuple[int, ...]] = {}
_GETTERS: dict[tuple[int, ...], Callable[[Sequence[Any]], tuple[Any, ...]]] = {}


def intern_ints(values: tuple[int, ...]) -> tuple[int, ...]:
    """One tuple object for every equal tuple of numbers (slots, offsets, lengths): machines polling alike
    hold the same ones, and a copy per machine and tick shape is memory for nothing."""
    found = _INTERNED.get(values)
    if found is None:
        if len(_INTERNED) >= INTERN_LIMIT:
            _INTERNED.clear()
        found = _INTERNED[values] = values
    return found


def slot_getter(slots: tuple[int, ...]) -> Callable[[Sequence[Any]], tuple[Any, ...]]:
    """`lambda seq: tuple(seq[s] for s in slots)`, in C (operator.itemgetter), and one per distinct tuple."""
    getter = _GETTERS.get(slots)
    if getter is None:
        if len(_GETTERS) >= INTERN_LIMIT:
            _GETTERS.clear()
        if len(slots) == 1:
            getter = _one_slot_getter(slots[0])
        elif slots:
            getter = itemgetter(*slots)
        else:
            getter = _no_slots
        _GETTERS[slots] = getter
    return getter


def _one_slot_getter(slot: int) -> Callable[[Sequence[Any]], tuple[Any, ...]]:
    return lambda seq: (seq[slot],)


def _no_slots(seq: Sequence[Any]) -> tuple[Any, ...]:
    return ()


class AnswerMemo:
    """One session's last answer bytes of every subpacket slot, shared by all its request PDUs.

    A poller's ticks send a few combinations of its groups (tick shapes), and most subpackets are in all of
    them: one copy of each subpacket's last answer per session, not one per shape. A slot is one call of one
    item; `generation` counts the changes of any slot's length, which moves the layout of every PDU that
    holds the slot (each AnswerSplitter checks its lengths again when it sees a new generation).
    """

    __slots__ = ("generation", "pieces")

    def __init__(self) -> None:
        self.pieces: list[bytes] = []
        self.generation = 0

    def allocate(self, count: int) -> range:
        """`count` new slots, not answered yet."""
        start = len(self.pieces)
        self.pieces += [NOT_ANSWERED] * count
        return range(start, start + count)


class AnswerSplitter:
    """split_response for the answers to ONE repeated request PDU (a poll tick), against the last answers.

    Most subpackets of a poll answer repeat byte for byte, at the same offsets. While the body keeps its
    size and count, each slot's last answer (in the session's AnswerMemo, whichever PDU brought it) is
    compared with the bytes at its offset, in C (the body cut into its pieces by one struct unpack); only a
    subpacket that differs is parsed (and checked) again. A changed piece whose length moved, or a body of
    another size, is split from scratch. `split` says which subpackets moved (by their bytes, after a split
    from scratch too: a string that changed length moves the offsets, not the other answers; None the first
    time) and gives their answers; `answer` parses any other subpacket of the same body when a caller needs it
    (an item with several calls, an error retried). Per PDU only numbers are kept (offsets, lengths and the struct that
    cuts the body, shared between equal layouts), no answer.
    """

    __slots__ = ("_cut", "_echoes", "_generation", "_get", "_head", "_indices", "_lengths", "_memo", "_offsets",
                 "_size", "_slots")

    def __init__(self, echoes: Sequence[Echo], slots: tuple[int, ...], memo: AnswerMemo) -> None:
        if len(slots) != len(echoes):
            raise ValueError(f"{len(slots)} answer slots for {len(echoes)} subpackets")
        self._echoes = tuple(echoes)
        self._slots = intern_ints(slots)
        self._get = slot_getter(self._slots)
        self._memo = memo
        self._head = _count_word(len(self._echoes))
        self._indices = range(len(self._echoes))
        self._size = -1  # no answer yet
        self._offsets: tuple[int, ...] = ()
        self._lengths: tuple[int, ...] = ()
        self._cut = _NO_CUT  # the body of _size bytes -> its pieces, by _lengths
        self._generation = -1

    def split(self, body: bytes) -> tuple[Sequence[Answer | None], list[int] | None]:
        """Which subpackets moved since their last answers (None: this splitter's first answer, so every item
        of the PDU is new to its caller, those that ask nothing too) and, per subpacket, its answer where it was
        parsed (every one after a split from scratch; None where it did not move)."""
        memo = self._memo
        if len(body) == self._size and body.startswith(self._head):
            last = self._get(memo.pieces)
            if self._generation != memo.generation:  # a slot's length changed: do the lengths still fit?
                if tuple(map(len, last)) != self._lengths:
                    return self._split_anew(body)
                self._generation = memo.generation
            # The body cut into its pieces at the known offsets (one unpack), each compared with its last piece:
            # which subpackets are not what they were.
            new = self._cut.unpack(body)
            moved = list(compress(self._indices, map(ne, new, last)))
            if not moved:
                return (), moved
            offsets = self._offsets
            lengths, echoes = self._lengths, self._echoes
            parsed = []
            for index in moved:
                answer, length = _one_answer(body, offsets[index], index, echoes[index])
                if length != lengths[index]:
                    break  # the layout moved: split from scratch (the memo is not touched yet)
                parsed.append(answer)
            else:
                answers: list[Answer | None] = [None] * len(offsets)
                pieces, slots = memo.pieces, self._slots
                for index, answer in zip(moved, parsed, strict=True):
                    answers[index] = answer
                    pieces[slots[index]] = new[index]
                return answers, moved
        return self._split_anew(body)

    def answer(self, body: bytes, index: int) -> Answer:
        """Subpacket `index` of the body `split` was just given."""
        return _one_answer(body, self._offsets[index], index, self._echoes[index])[0]

    def _split_anew(self, body: bytes) -> tuple[list[Answer], list[int] | None]:
        """Every subpacket parsed; moved are those whose bytes differ from their slot's last answer (a string
        that changed length moves the layout, not the other answers: they need no decoding again)."""
        first = not self._offsets
        self._size = -1  # until this answer is known good
        answers = split_response(body, self._echoes)
        offsets, lengths, offset = [], [], 2
        for _rc, _detail, payload in answers:
            offsets.append(offset)
            lengths.append(RESPONSE_SUBPACKET_FIXED + len(payload))
            offset += lengths[-1]
        memo = self._memo
        pieces = memo.pieces
        moved_layout = False
        moved = []
        for index, slot, start, length in zip(self._indices, self._slots, offsets, lengths, strict=True):
            moved_layout = moved_layout or len(pieces[slot]) != length
            piece = body[start : start + length]
            if piece != pieces[slot]:
                moved.append(index)
                pieces[slot] = piece
        if moved_layout:
            memo.generation += 1
        self._generation = memo.generation
        self._offsets, self._lengths = intern_ints(tuple(offsets)), intern_ints(tuple(lengths))
        self._cut = _body_cut(self._lengths)
        self._size = len(body)
        return answers, None if first else moved


_NO_CUT = struct.Struct("")
_CUTS: dict[tuple[int, ...], struct.Struct] = {}


def _body_cut(lengths: tuple[int, ...]) -> struct.Struct:
    """A struct that cuts a data response body (its count word, then subpackets of these lengths) into the
    subpackets' bytes: one per layout, shared by every splitter that has it (INTERN_LIMIT bounds the cache)."""
    found = _CUTS.get(lengths)
    if found is None:
        if len(_CUTS) >= INTERN_LIMIT:
            _CUTS.clear()
        found = _CUTS[lengths] = struct.Struct(">2x" + "".join(f"{length}s" for length in lengths))
    return found


_COUNT_WORDS: dict[int, bytes] = {}


def _count_word(count: int) -> bytes:
    word = _COUNT_WORDS.get(count)
    if word is None:
        word = _COUNT_WORDS[count] = U16_LAYOUT.pack(count)
    return word


# ---- whole PDUs -----------------------------------------------------------------------------------------


def encode_request(subpackets: Sequence[RequestSubpacket]) -> bytes:
    """A complete 0x2101 data request PDU."""
    return Frame(REQUEST_VERSION, PduType.DATA_REQUEST, encode_request_body(subpackets)).encode()


def encode_response(subpackets: Sequence[ResponseSubpacket],
                    version: int = DEFAULT_RESPONSE_VERSION) -> bytes:
    """A complete 0x2102 data response PDU (what the simulated CNC sends)."""
    return Frame(version, PduType.DATA_RESPONSE, encode_response_body(subpackets)).encode()


def encode_open_request(stream: OpenStream = OpenStream.DATA) -> bytes:
    return Frame(REQUEST_VERSION, PduType.OPEN_REQUEST, U16_LAYOUT.pack(stream)).encode()


def encode_open_response(payload: bytes = b"", version: int = DEFAULT_RESPONSE_VERSION) -> bytes:
    """Clients check only the type; the 360-byte payload a 31i sends is undocumented."""
    return Frame(version, PduType.OPEN_RESPONSE, payload).encode()


def encode_close_request() -> bytes:
    return Frame(REQUEST_VERSION, PduType.CLOSE_REQUEST, b"").encode()


def encode_close_response(version: int = DEFAULT_RESPONSE_VERSION) -> bytes:
    return Frame(version, PduType.CLOSE_RESPONSE, b"").encode()


def decode_frame(data: bytes, versions: Iterable[int] = ACCEPTED_VERSIONS) -> Frame:
    """Exactly one frame, no more and no less."""
    decoder = FrameDecoder(versions=versions)
    frames = decoder.feed(data)
    if len(frames) != 1 or decoder.buffered:
        raise ProtocolError(f"expected exactly one frame in {len(data)} bytes, got {len(frames)} frame(s) "
                            f"and {decoder.buffered} bytes left over")
    return frames[0]


class FrameDecoder:
    """Incremental frame decoder: feed it whatever a read returned, get every frame it completed.

    A frame may arrive split over many reads, and one read may hold several frames. The sync word is
    checked byte by byte as it arrives, so garbage fails at once instead of waiting for a header; the
    length is bounded by `max_body`, so a peer can never make it buffer without limit. After an error
    the decoder stays failed (the stream position is lost): the session must be reset.
    """

    def __init__(self, versions: Iterable[int] = ACCEPTED_VERSIONS, max_body: int = MAX_BODY_LENGTH) -> None:
        # The default set is shared, not copied: a frozenset is ~0.2 kB a session.
        self._versions = versions if isinstance(versions, frozenset) else frozenset(versions)
        self._max_body = max_body
        self._buffer = bytearray()
        self._error: ProtocolError | None = None

    @property
    def buffered(self) -> int:
        """Bytes received that do not yet form a complete frame."""
        return len(self._buffer)

    def feed(self, data: bytes) -> list[Frame]:
        if self._error is not None:
            raise ProtocolError(f"stream already failed: {self._error}")
        self._buffer += data
        frames: list[Frame] = []
        try:
            while (frame := self._next_frame()) is not None:
                frames.append(frame)
        except ProtocolError as exc:
            self._error = exc
            raise
        return frames

    def _next_frame(self) -> Frame | None:
        buf = self._buffer
        prefix = bytes(buf[: len(SYNC)])
        if prefix != SYNC[: len(prefix)]:
            raise ProtocolError(f"expected sync a0a0a0a0 at frame start, got {prefix.hex()}")
        if len(buf) < HEADER_SIZE:
            return None
        _, version, ftype, length = _HEADER.unpack_from(buf, 0)
        if version not in self._versions:
            raise ProtocolError(f"expected header version in {sorted(self._versions)}, got {version} "
                                f"(type 0x{ftype:04x})")
        if length > self._max_body:
            raise ProtocolError(f"frame type 0x{ftype:04x} declares {length} body bytes, more than the "
                                f"limit {self._max_body}")
        end = HEADER_SIZE + length
        if len(buf) < end:
            return None
        body = bytes(buf[HEADER_SIZE:end])
        del buf[:end]
        return Frame(version, ftype, body)
