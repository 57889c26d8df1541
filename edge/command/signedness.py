"""One signed/unsigned reading per integer PMC data type and parameter type: the number the CNC holds.

A PMC byte, word or long and a byte/word/2-word parameter are bits; which number they are is a reading.
The gateway reads them one way (what polls publish and writes read back), so a write's value is turned
into that reading before an allow rule's bounds are checked: otherwise `max: 100` on a byte passes -1,
which lands as 255. A value that only fits the other reading (-1 for a byte, 65535 for a word) is
accepted where no bound applies (the bits are the same) and refused where one does.
"""

from __future__ import annotations

from dataclasses import dataclass

from edge.focas.model import ParamType, PmcType


@dataclass(frozen=True, slots=True)
class Reading:
    """How a `bits`-wide integer is read; `other_accepted`: the other reading is taken as a write value."""

    bits: int
    signed: bool
    other_accepted: bool = True

    @property
    def low(self) -> int:
        return -(1 << (self.bits - 1)) if self.signed else 0

    @property
    def high(self) -> int:
        return (1 << (self.bits - 1)) - 1 if self.signed else (1 << self.bits) - 1

    @property
    def accepted(self) -> tuple[int, int]:
        """Every value a write may give: this reading, plus the other one when it is accepted."""
        if not self.other_accepted:
            return self.low, self.high
        return -(1 << (self.bits - 1)), (1 << self.bits) - 1

    def describe(self) -> str:
        return f"{'signed' if self.signed else 'unsigned'} {self.low}..{self.high}"

    def held(self, value: int) -> int:
        """The number the CNC holds after writing `value` (a value of the accepted range)."""
        raw = value & ((1 << self.bits) - 1)
        return raw - (1 << self.bits) if self.signed and raw >> (self.bits - 1) else raw

    def is_other(self, value: int) -> bool:
        """`value` is written as the other reading (-1 to a byte, 65535 to a word)."""
        return not self.low <= value <= self.high


PMC_READINGS: dict[PmcType, Reading] = {
    PmcType.BYTE: Reading(8, signed=False),
    PmcType.WORD: Reading(16, signed=True),
    PmcType.LONG: Reading(32, signed=True),
}

# As the CNC reports them (IODBPSD): bit parameters 0..255, byte/word/2-word signed. FANUC documents some
# byte and word parameters as unsigned (0..255, 0..65535); those values are accepted where no bound applies
# and read back signed. 2-word parameters span +-999999999: 2^31 and above is never a 2-word value.
PARAM_READINGS: dict[ParamType, Reading] = {
    ParamType.BIT: Reading(8, signed=False, other_accepted=False),
    ParamType.BYTE: Reading(8, signed=True),
    ParamType.WORD: Reading(16, signed=True),
    ParamType.TWO_WORD: Reading(32, signed=True, other_accepted=False),
}
