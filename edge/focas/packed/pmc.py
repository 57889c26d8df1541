"""PMC ranges on the packed surface: IODBPMC (0x4002 read, 0x0104 write) and the seed's area codes."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from edge.focas.errors import EW_LENGTH, LengthError, OutOfRange, ProtocolError
from edge.focas.model import PmcType
from edge.focas.packed.commands import Command, body_after_status

# ---- IODBPMC (0x4002 read, 0x0104 write) ---------------------------------------------------------------
# IODBPMC: i16 type_a | i16 type_d | u16 datano_s | u16 datano_e (inclusive) | data (e - s + 1 bytes).
# type_a uses the seed's letter codes, which differ from the native protocol's (G0 F1 Y2 X3 A4 R5 ...).
PMC_TYPE_A: dict[str, int] = {
    "X": 1, "Y": 2, "F": 3, "G": 4, "R": 5, "T": 6, "C": 7, "D": 8, "K": 10, "A": 11, "E": 12,
}
PMC_AREA_BY_TYPE_A: dict[int, str] = {code: area for area, code in PMC_TYPE_A.items()}
PMC_MAX_WRITE = 32
_IODBPMC_HEAD = struct.Struct("<hhHH")
_PMC_ELEMENTS: dict[PmcType, struct.Struct] = {t: struct.Struct("<" + t.struct_code) for t in PmcType}


@dataclass(frozen=True, slots=True)
class PmcRange:
    """A decoded IODBPMC: area letter, data type, inclusive byte addresses, and the data (may be empty)."""

    area: str
    data_type: int
    start: int
    end: int
    data: bytes = b""

    @property
    def byte_count(self) -> int:
        return self.end - self.start + 1


def pmc_type_a(area: str) -> int:
    try:
        return PMC_TYPE_A[area.upper()]
    except KeyError:
        raise OutOfRange(
            4, "IODBPMC", message=f"PMC area {area!r} has no packed type_a code (have {''.join(PMC_TYPE_A)})"
        ) from None


def encode_pmc_write(area: str, start: int, data: bytes) -> bytes:
    """0x0104 request: byte writes only (type_d 0), at most 32 bytes (the caller chunks)."""
    if not 1 <= len(data) <= PMC_MAX_WRITE:
        raise LengthError(EW_LENGTH, "pmc_wrpmcrng",
                         message=f"expected 1..{PMC_MAX_WRITE} bytes per call, got {len(data)}")
    return _IODBPMC_HEAD.pack(pmc_type_a(area), PmcType.BYTE, start, start + len(data) - 1) + bytes(data)


def encode_pmc_read(area: str, start: int, end: int, data_type: int = PmcType.BYTE) -> bytes:
    """0x4002 request: the IODBPMC header alone."""
    return _IODBPMC_HEAD.pack(pmc_type_a(area), data_type, start, end)


def encode_pmc_range(rng: PmcRange) -> bytes:
    """IODBPMC with its data: the 0x0104 request and the 0x4002 response body."""
    return _IODBPMC_HEAD.pack(pmc_type_a(rng.area), rng.data_type, rng.start, rng.end) + rng.data


class PmcCodeError(ProtocolError):
    """An IODBPMC names a type_a the surface does not define (the server answers EW_ATTRIB)."""


def decode_pmc_range(payload: bytes, with_data: bool, what: str = "IODBPMC") -> PmcRange:
    """Parse IODBPMC; with_data demands exactly (e - s + 1) data bytes, else none at all."""
    if len(payload) < _IODBPMC_HEAD.size:
        raise ProtocolError(f"{what}: expected an 8-byte IODBPMC header, got {len(payload)} bytes")
    type_a, type_d, start, end = _IODBPMC_HEAD.unpack_from(payload)
    data = payload[_IODBPMC_HEAD.size :]
    if end < start:
        raise ProtocolError(f"{what}: datano_e {end} is before datano_s {start}")
    expected = end - start + 1 if with_data else 0
    if len(data) != expected:
        raise ProtocolError(
            f"{what}: datano {start}..{end} needs exactly {expected} data bytes, got {len(data)}"
        )
    area = PMC_AREA_BY_TYPE_A.get(type_a)
    if area is None:
        raise PmcCodeError(f"{what}: unknown type_a {type_a} (expected one of {sorted(PMC_AREA_BY_TYPE_A)})")
    return PmcRange(area, type_d, start, end, data)


def pmc_values(data_type: int, data: bytes) -> list[int | float]:
    """Split PMC data into elements of data_type (little-endian; bytes unsigned)."""
    try:
        element = _PMC_ELEMENTS[PmcType(data_type)]
    except ValueError:
        raise ProtocolError(f"IODBPMC: unknown type_d {data_type}") from None
    if len(data) % element.size:
        raise ProtocolError(
            f"IODBPMC: {len(data)} data bytes are not a whole number of {element.size}-byte elements"
        )
    return [v for (v,) in element.iter_unpack(data)]


def decode_pmc_read_response(payload: bytes) -> PmcRange:
    return decode_pmc_range(body_after_status(payload, Command.RDPMCRNG), True, "pmc_rdpmcrng")
