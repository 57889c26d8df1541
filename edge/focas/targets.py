"""Target strings: what a read or write addresses, parsed into small frozen values.

One grammar serves the CLI (`focas-edge read/write`), the JSON command topic and the write allow-list
in the config, so the three can never disagree about what `pmc:R100.3` means:

    macro:500            macro:500-505
    pmc:R100             pmc:R100-R103          pmc:R100.3 (bit 3)       pmc:D2204.word   pmc:D2204-D2207.word
    param:6711           param:1815/1 (axis 1)  param:1815/0.3 (axis 0, bit 3)          param:6711.2
    param:1850/all (every axis, read-only)      diag:980             diag:980-981/1        diag:308-309/all
    sysinfo status alarms program programs positions axes spindles speeds loads timers messages tool_offsets
    work_offsets modal tool_number clock
                                                            (read-only names, whole-CNC reads)

PMC addresses are byte addresses and ranges are inclusive, as pmc_rdpmcrng counts them: a typed range
`D2204-D2207.word` is two words (bytes 2204..2207), so its length must be a whole number of elements;
a single typed element `D2204.word` is bytes 2204..2205.
A bit is addressed on a single byte (PMC) or a single number (parameter), never on a range.

A write or read names its CNC path with a suffix `@N` (`macro:500@2`, `pmc:R100.3@2`, `param:1825/1@2`):
`split_path` takes it off before the grammar above applies; without one, path 1 (or the device's own) is meant.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from edge.focas.model import PMC_AREAS, PmcType
from edge.focas.paths import MAX_PATHS
from edge.focas.values import ALL_AXES


class TargetError(ValueError):
    """A target string does not follow the grammar; the message names the string and what was wrong."""


MAX_MACRO = 99_999
MAX_PMC_ADDRESS = 65_535
MAX_PARAM = 65_535
MAX_AXIS = 32
MAX_PATH = MAX_PATHS  # `@N` names a path 1..MAX_PATH
# The named reads of `focas-edge read` (edge/cli/named_reads.py says what each reads).
READ_NAMES = ("sysinfo", "status", "alarms", "program", "programs", "positions", "axes", "spindles", "speeds",
              "loads", "timers", "messages", "tool_offsets", "work_offsets", "modal",
              "tool_number", "clock")
PMC_TYPE_NAMES: dict[str, PmcType] = {
    "byte": PmcType.BYTE,
    "word": PmcType.WORD,
    "long": PmcType.LONG,
    "float": PmcType.FLOAT,
    "double": PmcType.DOUBLE,
}


@dataclass(frozen=True, slots=True)
class MacroTarget:
    """Custom macro variables #first..#last."""

    first: int
    last: int

    @property
    def count(self) -> int:
        return self.last - self.first + 1

    def __str__(self) -> str:
        return f"macro:{_span(self.first, self.last)}"


@dataclass(frozen=True, slots=True)
class PmcTarget:
    """PMC bytes start..end (inclusive) of one area, read as `data_type` elements; or one bit of one byte."""

    area: str
    start: int
    end: int
    data_type: PmcType = PmcType.BYTE
    bit: int | None = None

    @property
    def count(self) -> int:
        """Number of data_type elements in the range."""
        return (self.end - self.start + 1) // self.data_type.width

    def __str__(self) -> str:
        text = f"pmc:{self.area}{self.start}"
        if self.end != self.start + self.data_type.width - 1:
            text += f"-{self.area}{self.end}"
        if self.bit is not None:
            text += f".{self.bit}"
        elif self.data_type is not PmcType.BYTE:
            text += f".{self.data_type.name.lower()}"
        return text


@dataclass(frozen=True, slots=True)
class ParamTarget:
    """CNC parameters first..last for one axis (0 = the whole CNC, -1 = every axis), or one bit of one."""

    first: int
    last: int
    axis: int = 0
    bit: int | None = None

    def __str__(self) -> str:
        return "param:" + _numbered_suffix(self.first, self.last, self.axis, self.bit)


@dataclass(frozen=True, slots=True)
class DiagTarget:
    """Diagnosis numbers first..last for one axis (0 = the whole CNC, -1 = every axis); read-only."""

    first: int
    last: int
    axis: int = 0

    def __str__(self) -> str:
        return "diag:" + _numbered_suffix(self.first, self.last, self.axis, None)


@dataclass(frozen=True, slots=True)
class NamedTarget:
    """A whole-CNC read by name (sysinfo, status, alarms, program, positions, clock); read-only."""

    name: str

    def __str__(self) -> str:
        return self.name


Target = MacroTarget | PmcTarget | ParamTarget | DiagTarget | NamedTarget
WritableTarget = MacroTarget | PmcTarget | ParamTarget

_INT = r"(\d{1,9})"
_MACRO_RE = re.compile(rf"{_INT}(?:-{_INT})?", re.ASCII)
_PMC_RE = re.compile(rf"([A-Za-z]){_INT}(?:-([A-Za-z])?{_INT})?(?:\.(\w+))?", re.ASCII)
_NUMBERED_RE = re.compile(rf"{_INT}(?:-{_INT})?(?:/(\d{{1,9}}|all))?(?:\.{_INT})?", re.ASCII | re.IGNORECASE)


def parse_target(text: str) -> Target:
    """Parse any target string; raises TargetError naming the string and the problem."""
    if not isinstance(text, str):
        raise TargetError(f"target must be a string, got {type(text).__name__}")
    stripped = text.strip()
    if stripped.lower() in READ_NAMES:
        return NamedTarget(stripped.lower())
    kind, sep, rest = stripped.partition(":")
    if not sep:
        raise TargetError(
            f"{text!r}: expected KIND:ADDRESS (macro:, pmc:, param:, diag:) or one of {', '.join(READ_NAMES)}"
        )
    parser = _PARSERS.get(kind.strip().lower())
    if parser is None:
        raise TargetError(f"{text!r}: unknown kind {kind!r}; expected macro, pmc, param or diag")
    target: Target = parser(text, rest.strip())
    return target


_PATH_SUFFIX_RE = re.compile(r"(.*?)\s*@\s*(\d{1,9})\s*", re.ASCII | re.DOTALL)


def split_path(text: str) -> tuple[str, int | None]:
    """`macro:500@2` -> ("macro:500", 2); a target without `@` -> (text, None). TargetError for a bad `@N`."""
    if "@" not in text:
        return text, None
    match = _PATH_SUFFIX_RE.fullmatch(text)
    if match is None or "@" in match[1]:
        raise TargetError(f"{text!r}: expected TARGET@PATH with PATH a number 1..{MAX_PATH}, e.g. macro:500@2")
    path = int(match[2])
    if not 1 <= path <= MAX_PATH:
        raise TargetError(f"{text!r}: path {path} is not 1..{MAX_PATH}")
    return match[1], path


def parse_writable(text: str) -> WritableTarget:
    """Parse a target that can be written (macro, pmc, param); diag and named reads are refused."""
    target = parse_target(text)
    if isinstance(target, DiagTarget | NamedTarget):
        raise TargetError(f"{text!r}: {target} is read-only; writable kinds are macro, pmc and param")
    if isinstance(target, ParamTarget) and target.axis == ALL_AXES:
        raise TargetError(f"{text!r}: a parameter write names one axis (/1, /2 ...), not /all")
    return target


def parse_assignment(text: str) -> tuple[WritableTarget, str]:
    """Split `TARGET=VALUE` (the CLI write form) into the parsed target and the raw value text."""
    target_text, sep, value = text.partition("=")
    if not sep or not value.strip():
        raise TargetError(f"{text!r}: expected TARGET=VALUE, e.g. macro:500=1.25 or pmc:R100.3=1")
    return parse_writable(target_text), value.strip()


def _parse_macro(text: str, rest: str) -> MacroTarget:
    match = _MACRO_RE.fullmatch(rest)
    if match is None:
        raise TargetError(f"{text!r}: expected macro:N or macro:N-M with N, M macro numbers")
    first = int(match[1])
    last = int(match[2]) if match[2] else first
    _check_span(text, "macro", first, last, MAX_MACRO)
    return MacroTarget(first, last)


def _parse_pmc(text: str, rest: str) -> PmcTarget:
    match = _PMC_RE.fullmatch(rest)
    if match is None:
        raise TargetError(
            f"{text!r}: expected pmc:<area><address>[-<area><address>][.<bit>|.<type>], e.g. pmc:R100.3"
        )
    area = match[1].upper()
    if area not in PMC_AREAS:
        raise TargetError(f"{text!r}: unknown PMC area {area!r}; expected one of {' '.join(PMC_AREAS)}")
    if match[3] and match[3].upper() != area:
        raise TargetError(f"{text!r}: a range stays in one area, got {area} and {match[3].upper()}")
    start = int(match[2])
    last = int(match[4]) if match[4] else start
    _check_span(text, "PMC address", start, last, MAX_PMC_ADDRESS)
    suffix = (match[5] or "").lower()
    if suffix.isdigit():
        bit = int(suffix)
        if bit > 7:
            raise TargetError(f"{text!r}: bit {bit} is not 0..7")
        if last != start:
            raise TargetError(f"{text!r}: a bit addresses one byte, not a range")
        return PmcTarget(area, start, start, PmcType.BYTE, bit)
    data_type = PmcType.BYTE
    if suffix:
        if suffix not in PMC_TYPE_NAMES:
            raise TargetError(f"{text!r}: unknown suffix .{suffix}; expected a bit 0..7 or one of "
                              f"{', '.join(PMC_TYPE_NAMES)}")
        data_type = PMC_TYPE_NAMES[suffix]
    end = pmc_end(text, area, start, last if match[4] else None, data_type)
    return PmcTarget(area, start, end, data_type)


def pmc_end(text: str, area: str, start: int, last: int | None, data_type: PmcType) -> int:
    """The last byte of a PMC range: `last` itself for a range, start + width - 1 for one element."""
    width = data_type.width
    if last is None:
        end = start + width - 1
        if end > MAX_PMC_ADDRESS:
            raise TargetError(f"{text!r}: ends at byte {end}, beyond {MAX_PMC_ADDRESS}")
        return end
    if (last - start + 1) % width:
        raise TargetError(
            f"{text!r}: {area}{start}-{area}{last} is {last - start + 1} bytes, not a whole number of "
            f"{data_type.name.lower()} ({width}-byte) elements"
        )
    return last


def _parse_param(text: str, rest: str) -> ParamTarget:
    first, last, axis, bit = _parse_numbered(text, rest, "param")
    if bit is not None and last != first:
        raise TargetError(f"{text!r}: a bit addresses one parameter, not a range")
    return ParamTarget(first, last, axis, bit)


def _parse_diag(text: str, rest: str) -> DiagTarget:
    first, last, axis, bit = _parse_numbered(text, rest, "diag")
    if bit is not None:
        raise TargetError(f"{text!r}: diagnosis targets have no bit form; read the whole number")
    return DiagTarget(first, last, axis)


def _parse_numbered(text: str, rest: str, kind: str) -> tuple[int, int, int, int | None]:
    match = _NUMBERED_RE.fullmatch(rest)
    if match is None:
        raise TargetError(f"{text!r}: expected {kind}:N[-M][/AXIS][.BIT], e.g. {kind}:1815/1")
    first = int(match[1])
    last = int(match[2]) if match[2] else first
    _check_span(text, kind, first, last, MAX_PARAM)
    axis = (ALL_AXES if match[3].lower() == "all" else int(match[3])) if match[3] else 0
    if axis > MAX_AXIS:
        raise TargetError(f"{text!r}: axis {axis} is not 0..{MAX_AXIS} (0 = whole CNC)")
    bit = int(match[4]) if match[4] else None
    if bit is not None and bit > 7:
        raise TargetError(f"{text!r}: bit {bit} is not 0..7")
    return first, last, axis, bit


def _check_span(text: str, what: str, first: int, last: int, maximum: int) -> None:
    if last > maximum or first > maximum:
        raise TargetError(f"{text!r}: {what} {max(first, last)} is beyond {maximum}")
    if last < first:
        raise TargetError(f"{text!r}: end {last} before start {first}")


def _span(first: int, last: int) -> str:
    return str(first) if first == last else f"{first}-{last}"


def _numbered_suffix(first: int, last: int, axis: int, bit: int | None) -> str:
    text = _span(first, last)
    if axis:
        text += "/all" if axis == ALL_AXES else f"/{axis}"
    if bit is not None:
        text += f"{'' if axis else '/0'}.{bit}"
    return text


_PARSERS: dict[str, Callable[[str, str], Target]] = {
    "macro": _parse_macro, "pmc": _parse_pmc, "param": _parse_param, "diag": _parse_diag}


# ---- allow-list patterns ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TargetPattern:
    """A write allow rule's target: a range of one kind that a write target must lie inside.

    `macro:500-599` covers macro:520; `pmc:R100-R199` covers any byte, bit or typed write whose bytes all
    lie in R100..R199; `param:1815` covers every axis and bit of 1815, `param:1815/1` only axis 1, and
    `param:1815/0.3` only that bit.
    """

    target: WritableTarget

    @classmethod
    def parse(cls, text: str) -> TargetPattern:
        return cls(parse_writable(text))

    def covers(self, target: Target) -> bool:
        rule = self.target
        if isinstance(rule, MacroTarget) and isinstance(target, MacroTarget):
            return rule.first <= target.first and target.last <= rule.last
        if isinstance(rule, PmcTarget) and isinstance(target, PmcTarget):
            inside = rule.area == target.area and rule.start <= target.start and target.end <= rule.end
            return inside and (rule.bit is None or rule.bit == target.bit)
        if isinstance(rule, ParamTarget) and isinstance(target, ParamTarget):
            inside = rule.first <= target.first and target.last <= rule.last
            axis_ok = (rule.axis == 0 and rule.bit is None) or rule.axis == target.axis
            return inside and axis_ok and (rule.bit is None or rule.bit == target.bit)
        return False

    def __str__(self) -> str:
        return str(self.target)
