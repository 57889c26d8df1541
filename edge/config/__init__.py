"""The daemon's configuration: one YAML file, validated completely before anything connects.

`load_config(path)` returns a Config or raises edge.ConfigError listing EVERY problem, each with its
path in the file (`machines[2].poll.pmc[0].range: end 100 before start 103`). Unknown keys are errors
(a typo must not silently fall back to a default). Secrets never live in the file: the MQTT password
comes from an environment variable (`password_env`) or a file (`password_file`, e.g. a systemd or
Docker secret); a literal `password:` key is refused.

Durations accept seconds as a number or a string with a unit (`250ms`, `1s`, `5m`, `1h`, `7d`). Soft
findings (a history depth clamped to 1..250) do not fail the load; they are listed in
`Config.warnings` for the caller to log.
"""

from __future__ import annotations

import os
import re
import types
import typing
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import yaml
from pydantic import (
    BaseModel,
    BeforeValidator,
    ByteSize,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from edge import ConfigError
from edge.config.lines import with_lines
from edge.config.merge import expand_machines
from edge.config.opcua import OpcUaConfig, opcua_secret_problems
from edge.focas.items import POSITION_KINDS
from edge.focas.model import PmcType
from edge.focas.paths import MAX_PATHS
from edge.focas.targets import (
    ALL_AXES,
    MAX_AXIS,
    MAX_MACRO,
    MAX_PARAM,
    PMC_TYPE_NAMES,
    PmcTarget,
    TargetError,
    TargetPattern,
    parse_target,
)

DEFAULT_STATE_DIR = Path("/var/lib/focas-edge")
HISTORY_DEPTH_MIN = 1
HISTORY_DEPTH_MAX = 250
NATIVE_PORT = 8193
Format = Literal["sparkplug", "json"]
FORMATS: tuple[Format, ...] = ("sparkplug", "json")
PositionKind = Literal["absolute", "machine", "relative", "distance"]
DEFAULT_POSITION: PositionKind = "absolute"
# Folders the collector's own metrics use; a configured name may not start with one of them.
RESERVED_FOLDERS = ("Status", "Program", "Spindle", "Axis", "Alarm", "Clock", "Feed", "Device",
                    "Node Control", "Device Control", "Properties")

# ---- small value types ---------------------------------------------------------------------------

_DURATION_RE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*(ms|s|m|min|h|d)?\s*", re.ASCII)
_DURATION_UNITS = {"ms": 0.001, "s": 1.0, None: 1.0, "m": 60.0, "min": 60.0, "h": 3600.0,
                   "d": 86400.0}


def _parse_duration(value: object) -> object:
    """Seconds as a number, or a string with a unit; anything else is left for the float check."""
    if isinstance(value, str):
        match = _DURATION_RE.fullmatch(value)
        if match is None:
            raise ValueError(f"expected a duration like 250ms, 1s, 5m, 2h, 7d or a number of seconds, got {value!r}")
        return float(match[1]) * _DURATION_UNITS[match[2]]
    if isinstance(value, bool):
        raise ValueError(f"expected a duration, got {value!r}")
    return value


Duration = Annotated[float, BeforeValidator(_parse_duration), Field(gt=0)]
SHORTEST_PERIOD_S = 0.05
Period = Annotated[float, BeforeValidator(_parse_duration), Field(ge=SHORTEST_PERIOD_S)]
AUTO_POLL_GRID_CAP_S = 0.05  # `poll_grid_s: auto`: half the fleet's fastest period, never coarser than this


def _parse_grid(value: object) -> object:
    """`auto` (None: derived from the periods) or a duration."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "auto"):
        return None
    return _parse_duration(value)


PollGrid = Annotated[Annotated[float, Field(gt=0, le=0.1)] | None, BeforeValidator(_parse_grid)]


def check_sparkplug_id(value: str) -> str:
    """Sparkplug group/edge node/device ids: non-empty UTF-8 without + / # (they are topic levels)."""
    if not value:
        raise ValueError("must not be empty")
    bad = sorted({ch for ch in value if ch in "+/#"})
    if bad:
        raise ValueError(f"{value!r} contains {' '.join(bad)}; Sparkplug ids may not contain + / #")
    if any(ord(ch) < 0x20 or ord(ch) == 0x7F for ch in value):
        raise ValueError(f"{value!r} contains control characters")
    if value != value.strip():
        raise ValueError(f"{value!r} has leading or trailing spaces")
    return value


SparkplugId = Annotated[str, BeforeValidator(lambda v: check_sparkplug_id(v) if isinstance(v, str) else v)]


def check_metric_name(value: str) -> str:
    """A metric name: folders separated by '/', no empty folder, no MQTT wildcards."""
    if not value or any(not part.strip() for part in value.split("/")):
        raise ValueError(f"{value!r} is not a metric name: folders separated by '/', none empty")
    if "+" in value or "#" in value or any(ord(ch) < 0x20 for ch in value):
        raise ValueError(f"{value!r}: metric names may not contain + # or control characters")
    return value


MetricName = Annotated[str, BeforeValidator(lambda v: check_metric_name(v) if isinstance(v, str) else v)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _at(path: str, message: str) -> ValueError:
    """A cross-field error reported at `path` below the model that raises it."""
    return ValueError(f"@{path}@{message}")


# ---- mqtt ------------------------------------------------------------------------------------------


class TlsConfig(_Model):
    ca_file: Path | None = None
    cert_file: Path | None = None
    key_file: Path | None = None
    insecure_skip_verify: bool = False

    @field_validator("ca_file", "cert_file", "key_file")
    @classmethod
    def _readable(cls, value: Path | None) -> Path | None:
        if value is not None and not value.is_file():
            raise ValueError(f"no such file: {value}")
        return value

    @model_validator(mode="after")
    def _key_needs_cert(self) -> TlsConfig:
        if self.key_file is not None and self.cert_file is None:
            raise _at("key_file", "a client key needs cert_file too")
        return self


class SparkplugConfig(_Model):
    group_id: SparkplugId
    edge_node_id: SparkplugId
    primary_host_id: SparkplugId | None = None


class JsonConfig(_Model):
    prefix: str = "focas"

    @field_validator("prefix")
    @classmethod
    def _topic_prefix(cls, value: str) -> str:
        if not value or value.startswith("/") or value.endswith("/") or "//" in value:
            raise ValueError(f"{value!r}: expected topic levels like 'plant1/focas', no empty level")
        if "+" in value or "#" in value:
            raise ValueError(f"{value!r}: a topic prefix may not contain MQTT wildcards + #")
        return value


def _protocol(value: object) -> object:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return {5: "5", 3.1: "3.1.1"}.get(value, str(value))
    return {"5.0": "5", "311": "3.1.1", "v5": "5"}.get(str(value), value)


class MqttConfig(_Model):
    host: str = "localhost"
    port: int | None = Field(default=None, ge=1, le=65535)
    tls: TlsConfig | None = None
    username: str | None = None
    password: object = Field(default=None, exclude=True, repr=False)
    password_env: str | None = None
    password_file: Path | None = None
    protocol: Annotated[Literal["3.1.1", "5"], BeforeValidator(_protocol)] = "3.1.1"
    keepalive: int = Field(default=30, ge=5, le=65535)
    client_id: str | None = None
    formats: list[Format] = Field(default_factory=lambda: list(FORMATS))
    sparkplug: SparkplugConfig | None = None
    json_topics: JsonConfig = Field(default_factory=JsonConfig, alias="json")

    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    @field_validator("password")
    @classmethod
    def _no_literal_password(cls, value: object) -> None:
        if value is not None:
            raise ValueError("secrets do not belong in the config file (it gets copied, committed and "
                             "logged); use password_env: VARIABLE or password_file: /run/secrets/NAME")
        return None

    @field_validator("formats")
    @classmethod
    def _formats(cls, value: list[str]) -> list[str]:
        if not value:
            raise ValueError("at least one of sparkplug, json")
        if len(set(value)) != len(value):
            raise ValueError(f"{value}: a format is listed twice")
        return value

    @model_validator(mode="after")
    def _consistent(self) -> MqttConfig:
        for key, message in _mqtt_rules(self.formats, self.sparkplug, self.password_env, self.password_file,
                                        self.username):
            raise _at(key, message)
        return self

    @property
    def effective_port(self) -> int:
        return self.port or (8883 if self.tls else 1883)

    def read_password(self, environ: Mapping[str, str] | None = None) -> str | None:
        """The MQTT password from its environment variable or file; ConfigError if it cannot be had."""
        return read_secret(self.password_env, self.password_file, environ)


def read_secret(password_env: object, password_file: object, environ: Mapping[str, str] | None = None) -> str | None:
    """The MQTT password from an environment variable or a file; ConfigError naming the key if it cannot be had."""
    environ = os.environ if environ is None else environ
    if isinstance(password_env, str) and password_env:
        if password_env not in environ:
            raise ConfigError([f"mqtt.password_env: environment variable {password_env} is not set"])
        return environ[password_env]
    if isinstance(password_file, str | Path) and str(password_file):
        try:
            return Path(password_file).read_text(encoding="utf-8").rstrip("\r\n")
        except OSError as exc:
            raise ConfigError([f"mqtt.password_file: cannot read {password_file}: {exc.strerror}"]) from exc
    return None


# ---- poll plan ---------------------------------------------------------------------------------------


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


# ---- alarms, writes, machines ---------------------------------------------------------------------------


class AlarmsConfig(_Model):
    mode: Literal["ActiveOnly", "ActivePlusHistory"] = "ActiveOnly"
    history_interval: Duration = 300.0
    history_depth: int = 100

    @field_validator("history_depth")
    @classmethod
    def _clamp(cls, value: int) -> int:
        return min(max(value, HISTORY_DEPTH_MIN), HISTORY_DEPTH_MAX)


class AllowRule(_Model):
    """One allowed write target pattern, with optional value bounds (inclusive)."""

    target: str
    min: float | None = None
    max: float | None = None

    @field_validator("target")
    @classmethod
    def _pattern(cls, value: str) -> str:
        try:
            TargetPattern.parse(value)
        except TargetError as exc:
            raise ValueError(str(exc)) from None
        return value

    @field_validator("max")
    @classmethod
    def _ordered(cls, value: float | None, info: ValidationInfo) -> float | None:
        low = info.data.get("min")
        if value is not None and low is not None and value < low:
            raise ValueError(f"max {value} below min {low}")
        return value

    @property
    def pattern(self) -> TargetPattern:
        return TargetPattern.parse(self.target)


class RateLimit(_Model):
    """At most max_writes writes per `per_s` seconds, per machine."""

    max_writes: int = Field(default=10, ge=1)
    per_s: Duration = 60.0


class WritesConfig(_Model):
    enabled: bool = False
    allow: list[AllowRule] = Field(default_factory=list)
    rate_limit: RateLimit = Field(default_factory=RateLimit)
    reconnect_deadline_s: Duration = 10.0
    max_payload_bytes: int = Field(default=4096, ge=64, le=1_048_576)


class MachineWrites(_Model):
    """A machine's additions to the global write policy (the global `enabled` is the master switch)."""

    enabled: bool | None = None
    allow: list[AllowRule] = Field(default_factory=list)
    rate_limit: RateLimit | None = None


class WritePolicy(_Model):
    """The effective write policy of one machine: global rules plus the machine's own."""

    enabled: bool
    allow: tuple[AllowRule, ...]
    rate_limit: RateLimit
    reconnect_deadline_s: float
    max_payload_bytes: int


class Timeouts(_Model):
    connect_s: Duration = 5.0
    request_s: Duration = 5.0
    backoff_initial_s: Duration = 0.5
    backoff_max_s: Duration = 30.0


_PACKED_ADDRESS_RE = re.compile(r"tcp:[^:\s]+:\d{1,5}|unix:/\S+", re.ASCII)


class MachineConfig(_Model):
    id: SparkplugId
    host: str | None = None
    port: int = Field(default=NATIVE_PORT, ge=1, le=65535)
    transport: Literal["focas", "packed"] = "focas"
    address: str | None = None
    # A FOCAS library host (focas-edge fwlib-host) beside the native connection: alarm history and parameter
    # writes go there, every other function stays native (edge.focas.routed).
    fwlib_host: str | None = None
    series: str | None = None
    timezone: str = "UTC"
    timeouts: Timeouts = Field(default_factory=Timeouts)
    # Subpackets per request PDU (focas only). No public source states a control's limit; 32 is safe.
    max_subpackets: int | None = Field(default=None, ge=2, le=128)
    max_skew_s: Duration = 60.0
    poll: PollPlan = Field(default_factory=PollPlan)
    alarms: AlarmsConfig | None = None
    writes: MachineWrites | None = None
    # CNC paths to poll (a twin-turret lathe has 2): path 1 is this machine's device, path n the device
    # `<id>-path<n>` (see path_devices). `path` is the one this entry's session reads.
    paths: int = Field(default=1, ge=1, le=MAX_PATHS)
    path: int = Field(default=1, ge=1, le=MAX_PATHS)

    def path_devices(self) -> list[MachineConfig]:
        """This machine, then one entry per further path: same settings, id `<id>-path<n>`, path n."""
        others = [self.model_copy(update={"id": f"{self.id}-path{n}", "path": n, "paths": 1})
                  for n in range(2, self.paths + 1)]
        return [self, *others]

    @field_validator("timezone")
    @classmethod
    def _zone(cls, value: str) -> str:
        try:
            ZoneInfo(value)
        except (ZoneInfoNotFoundError, ValueError):
            raise ValueError(f"unknown IANA time zone {value!r} (e.g. UTC, Europe/Berlin, America/Chicago)") \
                from None
        return value

    @field_validator("address", "fwlib_host")
    @classmethod
    def _address(cls, value: str | None) -> str | None:
        if value is not None and not _PACKED_ADDRESS_RE.fullmatch(value):
            raise ValueError(f"expected tcp:HOST:PORT or unix:/PATH, got {value!r}")
        return value

    @model_validator(mode="after")
    def _endpoint(self) -> MachineConfig:
        for key, message in _endpoint_rules(self.transport, self.host, self.address, self.max_subpackets,
                                            self.fwlib_host, self.paths):
            raise _at(key, message)
        return self

    @property
    def zone(self) -> ZoneInfo:
        return ZoneInfo(self.timezone)

    @property
    def endpoint(self) -> str:
        """The address open_session takes: host:port (focas), tcp:host:port or unix:/path (packed)."""
        if self.address is not None:
            return self.address
        if self.transport == "packed":
            return f"tcp:{self.host}:{self.port}"
        return f"{self.host}:{self.port}"


class HttpConfig(_Model):
    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = Field(default=9108, ge=1, le=65535)
    healthy_share: float = Field(default=0.5, ge=0.0, le=1.0)


class SpoolConfig(_Model):
    max_bytes: ByteSize = Field(default=ByteSize(256 * 1024 * 1024), ge=1024 * 1024)
    max_age_s: Duration = 7 * 24 * 3600.0


class Config(_Model):
    mqtt: MqttConfig
    machines: list[MachineConfig] = Field(min_length=1)
    alarms: AlarmsConfig = Field(default_factory=AlarmsConfig)
    writes: WritesConfig = Field(default_factory=WritesConfig)
    state_dir: Path | None = None
    http: HttpConfig = Field(default_factory=HttpConfig)
    spool: SpoolConfig = Field(default_factory=SpoolConfig)
    opcua: OpcUaConfig = Field(default_factory=OpcUaConfig)
    # Poll wake-ups are rounded up to this grid, so the machines due in one slot share one event-loop turn
    # (docs/performance.md): a poll is at most this much later than due, never earlier, never skipped.
    # None is `auto` (the default): see poll_grid_step_s.
    poll_grid_s: PollGrid = None

    _warnings: list[str] = PrivateAttr(default_factory=list)
    _state_dir: Path = PrivateAttr(default=DEFAULT_STATE_DIR)

    @field_validator("machines")
    @classmethod
    def _unique_ids(cls, machines: list[MachineConfig]) -> list[MachineConfig]:
        for problem in _duplicate_ids({"machines": [{"id": m.id} for m in machines]}):
            raise ValueError("@" + problem.removeprefix("machines").replace(": ", "@", 1))
        ids = {m.id.lower(): m.id for m in machines}
        for machine in machines:
            for device in machine.path_devices()[1:]:
                if device.id.lower() in ids:
                    raise ValueError(f"machine {machine.id!r} polls {machine.paths} paths, so its path {device.path} "
                                     f"is the device {device.id!r}, already a machine id")
        return machines

    @model_validator(mode="after")
    def _grid_fits_every_period(self) -> Config:
        if self.poll_grid_s is None:
            return self  # auto fits by construction
        for machine in self.machines:
            fastest = machine.poll.periods.fastest_s
            if self.poll_grid_s > fastest / 2:
                raise ValueError(f"poll_grid_s {self.poll_grid_s:g}s is more than half of machine {machine.id!r}'s "
                                 f"fastest poll period ({fastest:g}s): lower poll_grid_s to {fastest / 2:g}s or less")
        return self

    @property
    def poll_grid_step_s(self) -> float:
        """The grid in use: the configured one, or (auto) half the fleet's fastest period capped at 50 ms.

        Coarser is cheaper (more machines share a loop turn, docs/performance.md); a poll is at most one
        step late, and polls stay evenly spaced where the period is a multiple of the step. Half a period
        keeps every fleet spread over at least two slots of a period.
        """
        if self.poll_grid_s is not None:
            return self.poll_grid_s
        return min(AUTO_POLL_GRID_CAP_S, min(m.poll.periods.fastest_s for m in self.machines) / 2)

    @property
    def warnings(self) -> list[str]:
        return list(self._warnings)

    @property
    def resolved_state_dir(self) -> Path:
        """state_dir from the file, else $STATE_DIRECTORY (systemd), else /var/lib/focas-edge."""
        return self.state_dir if self.state_dir is not None else self._state_dir

    def devices(self) -> list[MachineConfig]:
        """Every polled device: each machine, and for a multi-path machine one entry per further path."""
        return [device for machine in self.machines for device in machine.path_devices()]

    def machine(self, machine_id: str) -> MachineConfig:
        for machine in self.devices():
            if machine.id == machine_id:
                return machine
        raise KeyError(machine_id)

    def alarms_for(self, machine: MachineConfig) -> AlarmsConfig:
        return machine.alarms if machine.alarms is not None else self.alarms

    def write_policy(self, machine: MachineConfig) -> WritePolicy:
        own = machine.writes or MachineWrites()
        return WritePolicy(
            enabled=self.writes.enabled and own.enabled is not False,
            allow=tuple(self.writes.allow) + tuple(own.allow),
            rate_limit=own.rate_limit or self.writes.rate_limit,
            reconnect_deadline_s=self.writes.reconnect_deadline_s,
            max_payload_bytes=self.writes.max_payload_bytes,
        )


# ---- loading ---------------------------------------------------------------------------------------------


def load_config(path: str | os.PathLike[str], environ: Mapping[str, str] | None = None) -> Config:
    """Read and validate a config file; ConfigError lists every problem with its path."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError([f"cannot read the file: {exc.strerror or exc}"], source) from exc
    except UnicodeDecodeError as exc:
        raise ConfigError([f"not UTF-8 text: {exc.reason} at byte {exc.start}"], source) from exc
    return parse_config(text, source, environ)


def parse_config(text: str, source: str = "config", environ: Mapping[str, str] | None = None) -> Config:
    """Validate config text (YAML); see load_config."""
    environ = os.environ if environ is None else environ
    data, expansion_problems = expand_machines(_parse_yaml(text, source))
    try:
        config = Config.model_validate(data)
        if expansion_problems:
            raise ConfigError(with_lines(expansion_problems, text), source)
    except ValidationError as exc:
        found = expansion_problems + format_errors(exc)
        found += [p for p in (*_duplicate_ids(data), *_mqtt_cross_checks(data), *_machine_cross_checks(data),
                                   *_secret_problems(data, environ),
                                   *opcua_secret_problems(data.get("opcua"), environ))
                  if p not in found]
        raise ConfigError(with_lines(found, text), source) from None
    problems = [*_secret_problems(data, environ), *opcua_secret_problems(data.get("opcua"), environ)]
    if problems:
        raise ConfigError(with_lines(problems, text), source)
    config._warnings.extend(_clamp_warnings(data))
    config._warnings.extend(_native_only_warnings(config))
    config._warnings.extend(config.opcua.warnings())
    state_directory = environ.get("STATE_DIRECTORY", "").split(":")[0]
    if state_directory:
        config._state_dir = Path(state_directory)
    return config


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last silently)."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: dict[Any, yaml.Mark] = {}
    for key_node, _value in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if isinstance(key, typing.Hashable) and key in seen:
            raise yaml.constructor.ConstructorError(
                "while reading a mapping", node.start_mark,
                f"key {key!r} given twice (first on line {seen[key].line + 1})", key_node.start_mark)
        if isinstance(key, typing.Hashable):
            seen[key] = key_node.start_mark
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _parse_yaml(text: str, source: str) -> dict[str, Any]:
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise ConfigError([f"{where}YAML syntax: {exc.problem or exc.context}"], source) from None
    except yaml.YAMLError as exc:
        raise ConfigError([f"YAML syntax: {exc}"], source) from None
    if data is None:
        raise ConfigError(["the file is empty; expected a mapping with mqtt: and machines:"], source)
    if not isinstance(data, dict):
        raise ConfigError([f"expected a mapping at the top level, got {type(data).__name__}"], source)
    return data


def format_errors(exc: ValidationError) -> list[str]:
    """pydantic errors as 'path: message' lines, paths written as in the file (machines[2].poll)."""
    problems = []
    for error in exc.errors():
        loc = list(error["loc"])
        message = str(error["msg"]).removeprefix("Value error, ").removeprefix("Assertion failed, ")
        if message.startswith("@"):
            sub, _, message = message[1:].partition("@")
            loc.extend(part for part in re.split(r"\.|(?=\[)", sub) if part)
        if error["type"] == "extra_forbidden":
            allowed = _allowed_keys(loc[:-1])
            message = "unknown key" + (f" (expected one of: {', '.join(allowed)})" if allowed else "")
        elif error["type"] == "missing":
            message = "required"
        problems.append(f"{format_path(loc)}: {message}")
    return problems


def format_path(loc: list[Any]) -> str:
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        elif isinstance(part, str) and part.startswith("["):
            text += part
        else:
            text += ("." if text else "") + str(part)
    return text or "(top level)"


def _allowed_keys(loc: list[Any]) -> list[str]:
    model: Any = Config
    for part in loc:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(part) or next(
            (f for f in model.model_fields.values() if f.alias == part), None)
        if field is None:
            return []
        found = _model_in(field.annotation)
        if found is None:
            return []
        model = found
    return sorted(field.alias or name for name, field in model.model_fields.items() if name != "password")


def _model_in(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is not None:
        for arg in typing.get_args(annotation):
            found = _model_in(arg)
            if found is not None:
                return found
    return None


def _clamp_warnings(data: dict[str, Any]) -> list[str]:
    sections: list[tuple[str, object]] = [("alarms", data.get("alarms"))]
    machines = data.get("machines")
    if isinstance(machines, list):
        sections += [(f"machines[{i}].alarms", m.get("alarms")) for i, m in enumerate(machines)
                     if isinstance(m, dict)]
    warnings = []
    for path, section in sections:
        depth = section.get("history_depth") if isinstance(section, dict) else None
        if isinstance(depth, int) and not HISTORY_DEPTH_MIN <= depth <= HISTORY_DEPTH_MAX:
            clamped = min(max(depth, HISTORY_DEPTH_MIN), HISTORY_DEPTH_MAX)
            warnings.append(f"{path}.history_depth: {depth} is outside {HISTORY_DEPTH_MIN}.."
                            f"{HISTORY_DEPTH_MAX} (the CNC ring holds at most {HISTORY_DEPTH_MAX}); "
                            f"using {clamped}")
    return warnings


def _native_only_warnings(config: Config) -> list[str]:
    """What a native-only machine (no fwlib_host) is set to publish but cannot: the wire has no public code for
    alarm history nor for the library-only poll flags (docs/protocol.md), so they would be dropped at once."""
    native_only = [(index, machine) for index, machine in enumerate(config.machines)
                   if machine.transport == "focas" and machine.fwlib_host is None]
    history = [
        f"machines[{index}] ({machine.id}): alarms mode ActivePlusHistory on the native transport alone: "
        f"the CNC's alarm history will NOT be published (no public wire code for cnc_rdalmhistry; "
        f"Plan/DroppedFunctions lists ReadAlarmHistory). Active alarms and the raise/clear events the "
        f"gateway derives from them at its poll rate (stamped with CNC time) WILL be published. "
        f"For the history, add fwlib_host: (a focas-edge fwlib-host, docs/install.md)"
        for index, machine in native_only if config.alarms_for(machine).mode == "ActivePlusHistory"]
    library = []
    for index, machine in native_only:
        poll = machine.poll
        flags = [name for name, on in (("work_offsets", bool(poll.work_offsets)), ("modal", poll.modal),
                                       ("tool_number", poll.tool_number)) if on]
        if flags:
            library.append(
                f"machines[{index}] ({machine.id}): poll {', '.join(flags)} on the native transport alone: "
                f"no public wire code exists for them, so they will NOT be published (Plan/DroppedFunctions "
                f"lists them). Add fwlib_host: (a focas-edge fwlib-host, docs/install.md)")
    return history + library


def _duplicate_ids(data: dict[str, Any]) -> Iterator[str]:
    """Machine ids used twice (ignoring case), read from the raw data so they show beside other errors."""
    machines = data.get("machines")
    seen: dict[str, int] = {}
    for index, machine in enumerate(machines if isinstance(machines, list) else []):
        machine_id = machine.get("id") if isinstance(machine, dict) else None
        if not isinstance(machine_id, str):
            continue
        first = seen.get(machine_id.lower())
        if first is not None:
            yield (f"machines[{index}].id: {machine_id!r} is already the id of machines[{first}]"
                   " (device ids are unique per edge node, ignoring case)")
        else:
            seen[machine_id.lower()] = index


def _mqtt_rules(formats: object, sparkplug: object, password_env: object,
                password_file: object, username: object) -> list[tuple[str, str]]:
    """Rules between mqtt keys as (key, message): one source for the model validator and for the raw
    re-check below."""
    rules = []
    if isinstance(formats, list) and "sparkplug" in formats and sparkplug is None:
        rules.append(("sparkplug", "required (group_id, edge_node_id) when formats includes sparkplug"))
    if password_env and password_file:
        rules.append(("password_file", "give password_env or password_file, not both"))
    if (password_env or password_file) and not username:
        rules.append(("username", "a password needs a username"))
    return rules


def _mqtt_cross_checks(data: dict[str, Any]) -> Iterator[str]:
    """The mqtt rules re-checked on the raw data: pydantic skips model validators when any field of the
    section is invalid, and a bad file must show every problem at once."""
    mqtt = data.get("mqtt")
    if not isinstance(mqtt, dict):
        return
    for key, message in _mqtt_rules(mqtt.get("formats", list(FORMATS)), mqtt.get("sparkplug"),
                                    mqtt.get("password_env"), mqtt.get("password_file"), mqtt.get("username")):
        yield f"mqtt.{key}: {message}"


def _endpoint_rules(transport: object, host: object, address: object,
                    max_subpackets: object, fwlib_host: object, paths: object = 1) -> list[tuple[str, str]]:
    """Rules between a machine's endpoint keys as (key, message), for the model and the raw re-check."""
    rules = []
    if transport == "focas" and address is not None:
        rules.append(("address", "only for transport packed; the focas transport uses host and port"))
    if host is None and address is None:
        rules.append(("host", "required" + (" (or address)" if transport == "packed" else "")))
    if host is not None and address is not None:
        rules.append(("address", "give host/port or address, not both"))
    if transport != "focas" and fwlib_host is not None:
        rules.append(("fwlib_host", "only beside the native transport (focas); with transport packed, address "
                                    "already names the library host"))
    if transport != "focas" and paths not in (1, None):
        rules.append(("paths", "only for transport focas (the packed surface reads path 1)"))
    if transport != "focas" and max_subpackets is not None:
        rules.append(("max_subpackets", "only for transport focas (the packed surface has no subpackets)"))
    return rules


def _machine_cross_checks(data: dict[str, Any]) -> Iterator[str]:
    """The endpoint rules re-checked on the raw data, for the same reason as _mqtt_cross_checks."""
    machines = data.get("machines")
    for index, machine in enumerate(machines if isinstance(machines, list) else []):
        if isinstance(machine, dict):
            for key, message in _endpoint_rules(machine.get("transport", "focas"), machine.get("host"),
                                                machine.get("address"), machine.get("max_subpackets"),
                                                machine.get("fwlib_host"), machine.get("paths", 1)):
                yield f"machines[{index}].{key}: {message}"


def _secret_problems(data: dict[str, Any], environ: Mapping[str, str]) -> list[str]:
    """The password cannot be had (read from the raw data, so it shows beside schema errors)."""
    mqtt = data.get("mqtt")
    if not isinstance(mqtt, dict):
        return []
    try:
        read_secret(mqtt.get("password_env"), mqtt.get("password_file"), environ)
    except ConfigError as exc:
        return exc.problems
    return []


def _strip_quote(message: str) -> str:
    """TargetError messages start with the quoted target; inside a config the path already says where."""
    return re.sub(r"^'[^']*': ", "", message)


def _wrap_at(path: str, check: Any, value: Any) -> None:
    try:
        check(value)
    except ValueError as exc:
        raise _at(path, str(exc)) from None
