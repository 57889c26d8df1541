"""The simulated CNC's PMC memory: one byte array per area (G, F, Y, X, A, R, T, K, C, D, E).

Sizes come from the profile. Reads return raw bytes or elements of a PMC data type (big-endian; bytes
unsigned, words signed); a write stores 1..32 bytes (more is EW_LENGTH, as pmc_wrpmcrng answers). A few
F/Y signals mirror the machine (MEM mode, cycle start, alarm, coolant): MachineState sets them, as a
ladder would.
"""

from __future__ import annotations

import struct

from edge.focas.errors import EW_ATTRIB, EW_LENGTH, EW_NUMBER, cnc_error
from edge.focas.model import PmcType
from edge.sim.profiles import Profile
from edge.sim.state_writes import WriteLog

PMC_WRITE_MAX = 32  # bytes per pmc_wrpmcrng call; more is EW_LENGTH


def _initial_pmc(profile: Profile) -> dict[str, bytearray]:
    areas = {area: bytearray(size) for area, size in profile.pmc_sizes.items()}
    areas["G"][8] = 0b0001_0000  # *ESP (G8.4) high = not in emergency stop
    areas["G"][12] = 155  # feed override *FV (negative logic)
    areas["G"][30] = 100  # spindle override SOV
    areas["X"][8] = 0b0001_0000  # *ESP input
    areas["D"][2204:2206] = (600).to_bytes(2, "big")  # the word PF's capture read back (600)
    areas["R"][100:104] = b"FOCS"
    areas["K"][0] = 0b1000_0001
    return areas


class PmcMemory:
    """One machine's PMC areas; MachineState holds the lock around every call (see edge.sim.state)."""

    def __init__(self, profile: Profile, writes: WriteLog) -> None:
        self.profile = profile
        self.areas = _initial_pmc(profile)
        self._writes = writes

    def area(self, area: str, function: str) -> bytearray:
        memory = self.areas.get(area.upper())
        if memory is None:
            raise cnc_error(EW_ATTRIB, function,
                            message=f"PMC area {area!r} not present; areas: {''.join(self.areas)}")
        return memory

    def read_bytes(self, area: str, start: int, end: int) -> bytes:
        memory = self.area(area, "pmc_rdpmcrng")
        if start < 0 or end < start or end >= len(memory):
            raise cnc_error(EW_NUMBER, "pmc_rdpmcrng", message=(
                f"{area}{start}-{area}{end} is outside {area}0-{area}{len(memory) - 1}"))
        return bytes(memory[start : end + 1])

    def read(self, area: str, start: int, end: int, data_type: PmcType | int) -> list[int | float]:
        try:
            kind = PmcType(data_type)
        except ValueError:
            raise cnc_error(EW_ATTRIB, "pmc_rdpmcrng", message=f"data type {data_type} unknown") from None
        if kind in (PmcType.FLOAT, PmcType.DOUBLE) and not self.profile.pmc_float_types:
            raise cnc_error(EW_ATTRIB, "pmc_rdpmcrng",
                            message=f"{self.profile.name} has no {kind.name} PMC data")
        count = (end - start + 1) // kind.width
        if count < 1:
            raise cnc_error(EW_LENGTH, "pmc_rdpmcrng", message=(
                f"{area}{start}-{area}{end} is shorter than one {kind.name} ({kind.width} bytes)"))
        raw = self.read_bytes(area, start, start + count * kind.width - 1)
        return list(struct.unpack(f">{count}{kind.struct_code}", raw))

    def write(self, area: str, start: int, data: bytes, protocol: str) -> None:
        if not 1 <= len(data) <= PMC_WRITE_MAX:
            raise cnc_error(EW_LENGTH, "pmc_wrpmcrng", message=(
                f"{len(data)} bytes in one write; expected 1..{PMC_WRITE_MAX}"))
        memory = self.area(area, "pmc_wrpmcrng")
        end = start + len(data) - 1
        if start < 0 or end >= len(memory):
            raise cnc_error(EW_NUMBER, "pmc_wrpmcrng", message=(
                f"{area}{start}-{area}{end} is outside {area}0-{area}{len(memory) - 1}"))
        old = bytes(memory[start : end + 1])
        memory[start : end + 1] = data
        target = f"pmc:{area.upper()}{start}" + (f"-{area.upper()}{end}" if end > start else "")
        self._writes.add(protocol, target, old, bytes(data))
