"""Macro variables on the packed surface: ODBM (0x0003 read, 0x0103 write)."""

from __future__ import annotations

import struct

from edge.focas.errors import ProtocolError
from edge.focas.packed.commands import I16, Command, body_after_status, unpack_exact
from edge.focas.packed.scaled import from_scaled, to_scaled

# ---- ODBM (0x0003 read, 0x0103 write) ------------------------------------------------------------------
# ODBM: i16 datano | i16 length (always 8) | i32 mcr_val | i16 dec_val. Value = mcr_val / 10**dec_val;
# a read with dec_val < 0 (the CNC answers mcr_val 0, dec_val -1) is a vacant variable.
_ODBM = struct.Struct("<hhih")
ODBM_LENGTH = 8
VACANT = (0, -1)


def encode_macro(number: int, value: float | None) -> bytes:
    """ODBM for `value` (None = vacant): the 0x0103 request and the 0x0003 response body alike."""
    mantissa, decimals = VACANT if value is None else to_scaled(value, f"macro #{number}")
    return _ODBM.pack(number, ODBM_LENGTH, mantissa, decimals)


def decode_macro(body: bytes, what: str = "ODBM") -> tuple[int, float | None]:
    number, length, mantissa, decimals = unpack_exact(_ODBM, body, what)
    if length != ODBM_LENGTH:
        raise ProtocolError(f"{what}: expected length field {ODBM_LENGTH}, got {length}")
    return number, None if decimals < 0 else from_scaled(mantissa, decimals)


def decode_macro_raw(body: bytes, what: str = "ODBM") -> tuple[int, int, int]:
    """(number, mcr_val, dec_val) as sent, for a server that stores the scaled form."""
    number, length, mantissa, decimals = unpack_exact(_ODBM, body, what)
    if length != ODBM_LENGTH:
        raise ProtocolError(f"{what}: expected length field {ODBM_LENGTH}, got {length}")
    return number, mantissa, decimals


def encode_macro_read(number: int) -> bytes:
    return I16.pack(number)


def decode_macro_read(payload: bytes) -> int:
    return int(unpack_exact(I16, payload, "cnc_rdmacro request")[0])


def decode_macro_response(payload: bytes) -> tuple[int, float | None]:
    return decode_macro(body_after_status(payload, Command.RDMACRO), "cnc_rdmacro")
