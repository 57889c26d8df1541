"""IPC framing of the packed-buffer surface, sans-IO: length-prefixed frames over a byte stream.

The seeds define payloads, not how they travel; this is our framing (docs/packed-protocol.md §2)::

    u32 LE length   bytes after this field (= 4 + len(payload)), 4 .. max_length
    u16 LE command  the command id; a response echoes its request's
    u16 LE seq      chosen by the client, echoed by the server (lets a client pipeline and check order)
    payload         the command's packed layout (edge.focas.packed)

Requests and responses share the format; the side of the socket says which is which. A frame whose
length is impossible makes the stream unusable: the decoder raises ProtocolError and stays failed.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from edge.focas.errors import ProtocolError

_HEADER = struct.Struct("<IHH")
LENGTH_SIZE = 4
HEADER_SIZE = _HEADER.size  # 8: length, command, seq
MIN_LENGTH = HEADER_SIZE - LENGTH_SIZE
# 256 KiB: ODBALMHIS at 250 entries of 32-character messages is ~13 KiB, a whole PMC area ~64 KiB.
MAX_LENGTH = 256 * 1024


@dataclass(frozen=True, slots=True)
class PackedFrame:
    """One request or response: command id, sequence number, payload."""

    command: int
    seq: int
    payload: bytes = b""

    def encode(self) -> bytes:
        length = MIN_LENGTH + len(self.payload)
        if length > MAX_LENGTH:
            raise ProtocolError(
                f"packed frame for command 0x{self.command:04X}: payload of {len(self.payload)} bytes "
                f"exceeds the {MAX_LENGTH - MIN_LENGTH}-byte limit"
            )
        if not (0 <= self.command <= 0xFFFF and 0 <= self.seq <= 0xFFFF):
            raise ProtocolError(f"packed frame: command {self.command} and seq {self.seq} must fit u16")
        return _HEADER.pack(length, self.command, self.seq) + self.payload


class FrameDecoder:
    """Incremental decoder: feed whatever the socket delivered, get every complete frame back.

    Partial frames wait for more bytes; a length outside MIN_LENGTH..max_length raises ProtocolError
    (and every later feed raises it again, since the stream has lost its frame boundaries).
    """

    def __init__(self, max_length: int = MAX_LENGTH) -> None:
        if max_length < MIN_LENGTH:
            raise ValueError(f"max_length must be at least {MIN_LENGTH}, got {max_length}")
        self.max_length = max_length
        self._buffer = bytearray()
        self._failure: ProtocolError | None = None

    @property
    def buffered(self) -> int:
        """Bytes held that do not yet make a whole frame."""
        return len(self._buffer)

    def feed(self, data: bytes) -> list[PackedFrame]:
        if self._failure is not None:
            raise ProtocolError(f"packed stream already failed: {self._failure}")
        self._buffer += data
        frames: list[PackedFrame] = []
        while len(self._buffer) >= LENGTH_SIZE:
            (length,) = struct.unpack_from("<I", self._buffer)
            if not MIN_LENGTH <= length <= self.max_length:
                self._failure = ProtocolError(
                    f"packed frame: expected a length of {MIN_LENGTH}..{self.max_length}, got {length} "
                    f"(first bytes {bytes(self._buffer[:8]).hex(' ')})"
                )
                raise self._failure
            total = LENGTH_SIZE + length
            if len(self._buffer) < total:
                break
            _, command, seq = _HEADER.unpack_from(self._buffer)
            frames.append(PackedFrame(command, seq, bytes(self._buffer[HEADER_SIZE:total])))
            del self._buffer[:total]
        return frames
