"""`poll:` what each machine reads and how often, and the fleet's poll grid.

Periods per poll group, macro ranges, PMC ranges (byte addresses read as typed elements or bits),
parameter and diagnosis numbers, and the switches of the built-in groups. Every configured value becomes
one metric; a PollPlan refuses two names that differ only in case, and names in the folders the
collector's own metrics use.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, ValidationInfo, field_validator, model_validator

from edge.config.fields import Duration, MetricName, _at, _Model, _parse_duration
from edge.focas.items import POSITION_KINDS
from edge.focas.model import PmcType
from edge.focas.targets import (
    ALL_AXES,
    MAX_AXIS,
    MAX_MACRO,
    MAX_PARAM,
    PMC_TYPE_NAMES,
    PmcTarget,
    TargetError,
    parse_target,
)

PositionKind = Literal["absolute", "machine", "relative", "distance"]
DEFAULT_POSITION: PositionKind = "absolute"
# Folders the collector's own metrics use; a configured name may not start with one of them.
RESERVED_FOLDERS = ("Status", "Program", "Spindle", "Axis", "Alarm", "Clock", "Feed", "Device",
                    "Node Control", "Device Control", "Properties")


SHORTEST_PERIOD_S = 0.05
Period = Annotated[float, BeforeValidator(_parse_duration), Field(ge=SHORTEST_PERIOD_S)]
AUTO_POLL_GRID_CAP_S = 0.05  # `poll_grid_s: auto`: half the fleet's fastest period, never coarser than this


def _parse_grid(value: object) -> object:
    """`auto` (None: derived from the periods) or a duration."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "auto"):
        return None
    return _parse_duration(value)


PollGrid = Annotated[Annotated[float, Field(gt=0, le=0.1)] | None, BeforeValidator(_parse_grid)]


def _folder_ok(name: str) -> str:
    if name.split("/", 1)[0] in RESERVED_FOLDERS:
        raise ValueError(f"{name!r}: the folder {name.split('/', 1)[0]!r} is reserved for built-in metrics")
    return name


class Periods(_Model):
    """How often each poll group is read (static data: once per connection)."""

    status: Period = 0.25
    macros: Period = 1.0
    pmc: Period = 1.0
    params: Period = 60.0
    diags: Period = 60.0
    loads: Period = 1.0  # servo load per axis
    counters: Period = 10.0  # timers (power-on, operating, cutting, cycle) and part totals

    @property
    def fastest_s(self) -> float:
        return min(self.status, self.macros, self.pmc, self.params, self.diags, self.loads, self.counters)


def _not_before(end: int | None, start: int | None) -> int | None:
    """The end of an inclusive range, refused when it lies before the start."""
    if end is not None and start is not None and end < start:
        raise ValueError(f"end {end} before start {start}")
    return end


def _macro_shorthand(value: object) -> object:
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        return {"first": value}
    if isinstance(value, str):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", value, re.ASCII)
        if match is None:
            raise ValueError(f"expected a macro number or range like 500-505, got {value!r}")
        return {"first": int(match[1]), "last": int(match[2] or match[1])}
    return value


class MacroRange(_Model):
    """Macro variables #first..#last, published as `<name_prefix>/<number>` (or `name` for one)."""

    first: int = Field(ge=0, le=MAX_MACRO)
    last: int | None = Field(default=None, ge=0, le=MAX_MACRO)
    name_prefix: MetricName = "Macro"
    name: MetricName | None = None
    deadband: float = Field(default=0.0, ge=0)

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, value: object) -> object:
        return _macro_shorthand(value)

    @field_validator("last")
    @classmethod
    def _ordered(cls, value: int | None, info: ValidationInfo) -> int | None:
        return _not_before(value, info.data.get("first"))

    @model_validator(mode="after")
    def _name_for_one(self) -> MacroRange:
        if self.name is not None and self.numbers != range(self.first, self.first + 1):
            raise _at("name", "a single name fits one macro; use name_prefix for a range")
        if self.name is not None:
            _wrap_at("name", _folder_ok, self.name)
        elif self.name_prefix != "Macro":
            _wrap_at("name_prefix", _folder_ok, self.name_prefix)
        return self

    @property
    def numbers(self) -> range:
        return range(self.first, (self.last if self.last is not None else self.first) + 1)

    def metric_name(self, number: int) -> str:
        return self.name if self.name is not None else f"{self.name_prefix}/{number}"


class PmcRange(_Model):
    """PMC bytes of one area read as typed elements, one metric per element (`PMC/D2204`); with
    data_type `bit`, one Boolean metric per bit (`PMC/R100.3`), the bytes read in one range read."""

    area: str | None = None
    range: str | None = None
    start: int | None = Field(default=None, ge=0)
    end: int | None = Field(default=None, ge=0)
    count: int | None = Field(default=None, ge=1)
    data_type: Literal["bit", "byte", "word", "long", "float", "double"] = "byte"
    name: MetricName | None = None
    deadband: float = Field(default=0.0, ge=0)

    @property
    def bits(self) -> bool:
        return self.data_type == "bit"

    @property
    def element_type(self) -> str:
        """The element width the range is read with (bits are read as their bytes)."""
        return "byte" if self.bits else self.data_type

    @field_validator("area")
    @classmethod
    def _area(cls, value: str | None) -> str | None:
        from edge.focas.model import PMC_AREAS

        if value is not None and value.upper() not in PMC_AREAS:
            raise ValueError(f"unknown PMC area {value!r}; expected one of {' '.join(PMC_AREAS)}")
        return value.upper() if value is not None else None

    @field_validator("range")
    @classmethod
    def _range(cls, value: str | None, info: ValidationInfo) -> str | None:
        if value is not None:
            cls._parse(value, info.data.get("area"), "byte")
        return value

    @field_validator("end")
    @classmethod
    def _ordered(cls, value: int | None, info: ValidationInfo) -> int | None:
        return _not_before(value, info.data.get("start"))

    @model_validator(mode="after")
    def _complete(self) -> PmcRange:
        if self.range is not None and (self.start is not None or self.end is not None):
            raise _at("range", "give range or start/end, not both")
        if self.range is None and self.start is None:
            raise _at("range", "required (e.g. range: R100-R103, or start: and end:)")
        if self.range is None and self.area is None:
            raise _at("area", "required with start/end (one of G F Y X A R T K C D M N E Z)")
        if self.count is not None and (self.end is not None or "-" in (self.range or "")):
            raise _at("count", "give count or an end address, not both")
        try:
            self.target  # noqa: B018 - validates the whole-element rule with the data type
            if self.bits and self.deadband:
                raise ValueError("a deadband means nothing for bits")
        except ValueError as exc:
            message = _strip_quote(str(exc))
            if "not a whole number" in message:
                message += ". " + self._meant()
            raise _at("range" if self.range is not None else "end", message) from None
        if self.name is not None:
            _wrap_at("name", _folder_ok, self.name)
        return self

    @staticmethod
    def _parse(text: str, area: str | None, data_type: str) -> PmcTarget:
        spec = text.strip()
        if area and spec[:1].isdigit():
            spec = area + spec
            if "-" in spec and spec.split("-", 1)[1][:1].isdigit():
                spec = spec.replace("-", "-" + area, 1)
        try:
            target = parse_target(f"pmc:{spec}.{data_type}")
        except TargetError as exc:
            raise ValueError(_strip_quote(str(exc))) from None
        assert isinstance(target, PmcTarget)
        if area and target.area != area:
            raise ValueError(f"range {text!r} is in area {target.area}, but area is {area}")
        return target

    @property
    def pmc_type(self) -> PmcType:
        return PMC_TYPE_NAMES[self.element_type]

    def _byte_span(self) -> PmcTarget:
        """The range as plain bytes, whatever the data type."""
        if self.range is not None:
            return self._parse(self.range, self.area, "byte")
        assert self.area is not None and self.start is not None
        last = self.end if self.end is not None else self.start
        target = parse_target(f"pmc:{self.area}{self.start}-{self.area}{last}.byte")
        assert isinstance(target, PmcTarget)
        return target

    def _meant(self) -> str:
        """What a byte range that is not whole elements was most likely meant to be, written both ways."""
        span = self._byte_span()
        width = PMC_TYPE_NAMES[self.element_type].width
        distance = span.end - span.start
        aligned = distance % width == 0
        count = distance // width + 1 if aligned else -(-(distance + 1) // width)
        kind = self.element_type + ("s" if count != 1 else "")
        whose = f" whose last starts at {span.area}{span.end}" if aligned else ""
        first = f"{span.area}{span.start}"
        return (f"A range is byte addresses: for {count} {kind}{whose} write "
                f"{first}-{span.area}{span.start + count * width - 1} or {{range: {first}, count: {count}}}")

    @property
    def target(self) -> PmcTarget:
        """The range as a PMC target (byte addresses, inclusive)."""
        if self.count is not None:
            first = self._byte_span()
            end = first.start + self.count * PMC_TYPE_NAMES[self.element_type].width - 1
            counted = parse_target(f"pmc:{first.area}{first.start}-{first.area}{end}.{self.element_type}")
            assert isinstance(counted, PmcTarget)
            return counted
        if self.range is not None:
            return self._parse(self.range, self.area, self.element_type)
        assert self.area is not None and self.start is not None
        last = self.end if self.end is not None else self.start
        text = f"pmc:{self.area}{self.start}" + (f"-{self.area}{last}" if self.end is not None else "")
        target = parse_target(f"{text}.{self.element_type}")
        assert isinstance(target, PmcTarget)
        return target

    def addresses(self) -> list[int]:
        """The byte address of each element."""
        target = self.target
        return list(range(target.start, target.end + 1, target.data_type.width))

    def metric_name(self, address: int, bit: int | None = None) -> str:
        target = self.target
        element = f"{target.area}{address}" + (f".{bit}" if bit is not None else "")
        if self.name is None:
            return f"PMC/{element}"
        single = len(self.addresses()) == 1 and bit is None
        return self.name if single else f"{self.name}/{element}"

    def metric_names(self) -> list[str]:
        """One name per element, or per bit (bit 0 first) of each byte for data_type bit."""
        if self.bits:
            return [self.metric_name(a, b) for a in self.addresses() for b in range(8)]
        return [self.metric_name(a) for a in self.addresses()]


class NumberedItem(_Model):
    """One parameter or diagnosis number for one axis (0 = the whole CNC; `all` = every axis in one
    read, published per axis name)."""

    number: int = Field(ge=0, le=MAX_PARAM)
    axis: int = Field(default=0, ge=ALL_AXES, le=MAX_AXIS)
    name: MetricName | None = None
    deadband: float = Field(default=0.0, ge=0)

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, value: object) -> object:
        if isinstance(value, int) and not isinstance(value, bool):
            return {"number": value}
        if isinstance(value, dict) and isinstance(value.get("axis"), str):
            if value["axis"].strip().lower() != "all":
                raise ValueError(f"axis must be 0..{MAX_AXIS} or 'all', got {value['axis']!r}")
            return {**value, "axis": ALL_AXES}
        return value

    @model_validator(mode="after")
    def _folder(self) -> NumberedItem:
        if self.name is not None:
            _wrap_at("name", _folder_ok, self.name)
        return self

    def metric_name(self, folder: str) -> str:
        if self.name is not None:
            return self.name
        return f"{folder}/{self.number}" + (f"/{self.axis}" if self.axis > 0 else "")


MAX_TOOL_OFFSETS = 400


class PollPlan(_Model):
    periods: Periods = Field(default_factory=Periods)
    positions: list[PositionKind] = Field(default_factory=lambda: [DEFAULT_POSITION])
    part_count: bool = True
    program_name: bool = True  # Program/Name and Program/MainPath (0xcf, 0xb9)
    servo_load: bool = True  # Axis/<name>/Load (0x56), loads period
    timers: bool = True  # Times/PowerOn, Operating, Cutting, Cycle (0x120), counters period
    operator_messages: bool = True  # Message/Operator (0x34), status group
    tool_offsets: int = Field(default=0, ge=0, le=MAX_TOOL_OFFSETS)  # offsets 1..n of each kind (0x08), counters
    # G54..G59 work-coordinate offsets to publish as WorkOffset/G5x/<axis> (cnc_rdzofs: FOCAS library
    # host only, no public wire form), counters period
    work_offsets: list[int] = Field(default_factory=list)
    modal: bool = False  # Modal/G: the active block's modal G codes (cnc_rdgcode, library host only), counters
    tool_number: bool = False  # Tool/Number: the T code in use (cnc_modal, library host only), counters
    macros: list[MacroRange] = Field(default_factory=list)
    pmc: list[PmcRange] = Field(default_factory=list)
    params: list[NumberedItem] = Field(default_factory=list)
    diags: list[NumberedItem] = Field(default_factory=list)
    # A function dropped after EW_FUNC/EW_NOOPT is tried again this long after (and at every reconnect).
    retry_dropped: Duration = 600.0

    @field_validator("positions")
    @classmethod
    def _kinds(cls, value: list[str]) -> list[str]:
        assert set(value) <= set(POSITION_KINDS)
        if len(set(value)) != len(value):
            raise ValueError(f"{value}: a position kind is listed twice")
        return value

    @field_validator("work_offsets")
    @classmethod
    def _work_offset_codes(cls, value: list[int]) -> list[int]:
        bad = [g for g in value if not 54 <= g <= 59]
        if bad:
            raise ValueError(f"work offset G{bad[0]}: expected G codes 54..59, e.g. [54, 55]")
        if len(set(value)) != len(value):
            raise ValueError(f"{value}: a work offset is listed twice")
        return value

    @model_validator(mode="after")
    def _unique_names(self) -> PollPlan:
        seen: dict[str, str] = {}
        for where, name in self.configured_metric_names():
            key = name.lower()
            if key in seen:
                raise _at(where, f"metric name {name!r} is already used by {seen[key]} "
                                 "(names must differ in more than case)")
            seen[key] = where
        return self

    def configured_metric_names(self) -> Iterator[tuple[str, str]]:
        """(path in the file, metric name) for every configured value."""
        for i, macro in enumerate(self.macros):
            for number in macro.numbers:
                yield f"macros[{i}]", macro.metric_name(number)
        for i, pmc in enumerate(self.pmc):
            for address in pmc.addresses():
                yield f"pmc[{i}]", pmc.metric_name(address)
        for i, param in enumerate(self.params):
            yield f"params[{i}]", param.metric_name("Param")
        for i, diag in enumerate(self.diags):
            yield f"diags[{i}]", diag.metric_name("Diag")
        for n in range(1, self.tool_offsets + 1):
            for folder in ("LengthGeometry", "LengthWear", "RadiusGeometry", "RadiusWear"):
                yield "tool_offsets", f"Tool/{n}/{folder}"
        if self.part_count:
            yield "part_count", "Counters/Parts"
            yield "part_count", "Counters/PartsTotal"
            yield "part_count", "Counters/PartsRequired"


def _strip_quote(message: str) -> str:
    """TargetError messages start with the quoted target; inside a config the path already says where."""
    return re.sub(r"^'[^']*': ", "", message)


def _wrap_at(path: str, check: Any, value: Any) -> None:
    try:
        check(value)
    except ValueError as exc:
        raise _at(path, str(exc)) from None
