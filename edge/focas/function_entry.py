"""What one entry of the FOCAS function table is (edge.focas.functions holds the table itself).

A Function names a FOCAS call (class, command, its five i32 args) and carries the codecs of both directions,
so the client and the simulated CNC build and parse every layout from the same entry; Context is what a
layout depends on beyond the bytes; Evidence says how well the public record pins a layout down.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from edge.focas.errors import cnc_error
from edge.focas.frame import RequestSubpacket, ResponseSubpacket
from edge.focas.model import SysInfo
from edge.focas.values import SlotForm


class Evidence(enum.Enum):
    """How well the public record pins a layout down (see docs/protocol.md)."""

    CAPTURE = "capture"
    DOC = "doc table"
    CODE = "code only"


@dataclass(frozen=True, slots=True)
class Context:
    """What a layout depends on beyond the bytes: the control's max_axis and record slot form."""

    max_axis: int = 8
    slot_form: SlotForm = SlotForm.FOUR_BYTE

    @classmethod
    def from_sysinfo(cls, info: SysInfo) -> Context:
        form = SlotForm.SCALED if info.is_30i_style else SlotForm.FOUR_BYTE
        return cls(max_axis=max(1, info.max_axis), slot_form=form)


PayloadDecoder = Callable[[bytes, RequestSubpacket, Context], Any]
PayloadEncoder = Callable[[Any, RequestSubpacket, Context], bytes]
ExtraDecoder = Callable[[RequestSubpacket, Context], Any]


def _empty_decode(payload: bytes, req: RequestSubpacket, ctx: Context) -> None:
    return None


def _empty_encode(value: Any, req: RequestSubpacket, ctx: Context) -> bytes:
    return b""


@dataclass(frozen=True, slots=True)
class Function:
    """One FOCAS function: identity, evidence, arg names, and the codecs of both directions."""

    name: str
    cls: int
    command: int
    evidence: Evidence
    args: tuple[str, ...]
    returns: str  # the typed value decode_payload gives and encode_payload takes
    layout: str  # the response payload (or, for writes, the request extra) in one line
    decode_payload: PayloadDecoder = _empty_decode
    encode_payload: PayloadEncoder = _empty_encode
    decode_extra: ExtraDecoder | None = None
    notes: str = ""
    aliases: tuple[str, ...] = field(default_factory=tuple)

    @property
    def is_write(self) -> bool:
        return self.decode_extra is not None

    def request(self, *args: int, extra: bytes = b"", arg5: int | None = None,
                path: int = 1) -> RequestSubpacket:
        """A request subpacket; args fill arg1.. in order, arg5 defaults to len(extra)."""
        if len(args) > 4:
            raise ValueError(f"{self.name}: at most 4 positional args (arg5 is the extra length)")
        padded = list(args) + [0] * (4 - len(args))
        a5 = len(extra) if arg5 is None else arg5
        return RequestSubpacket(self.cls, self.command, (padded[0], padded[1], padded[2], padded[3], a5),
                                extra, path)

    def named_args(self, req: RequestSubpacket) -> dict[str, int]:
        return dict(zip(self.args, req.args, strict=False))

    def response(self, req: RequestSubpacket, value: Any, ctx: Context) -> ResponseSubpacket:
        """Server side: the OK answer carrying `value`."""
        return ResponseSubpacket(req.cls, req.command, 0, 0, self.encode_payload(value, req, ctx), req.path)

    def decode_response(self, sub: ResponseSubpacket, req: RequestSubpacket, ctx: Context) -> Any:
        """Client side: the typed value, or raise the CNC's error for this subpacket."""
        if sub.rc != 0:
            raise cnc_error(sub.rc, self.name, sub.detail)
        return self.decode_payload(sub.payload, req, ctx)


def error_response(req: RequestSubpacket, rc: int, detail: int = 0) -> ResponseSubpacket:
    """Server side: a 16-byte error subpacket without payload (as the EDM capture shows for EW_FUNC)."""
    return ResponseSubpacket(req.cls, req.command, rc, detail, b"", req.path)
