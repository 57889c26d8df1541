"""Scenario files: a YAML description of a simulated fleet (machines, profiles, zones, clocks, faults).

    host: 127.0.0.1
    base_port: 8193          # machine i listens on base_port + i (0: any free port)
    packed_base_port: 8293   # optional: also serve the packed surface on consecutive ports
    admin_port: 8190         # optional: the HTTP/JSON admin endpoint (edge.sim.admin)
    machines:
      - name: mill-1
        profile: 30i
        timezone: Europe/Berlin
        clock_offset: 12.5   # seconds the CNC clock runs ahead of real time
        cycle: {cut_seconds: 12, idle_seconds: 4, alarm_every: 3}
        macros: {500: 1.5}
        param_write_enabled: false
        faults: {latency: 0.05}
      - name: lathe
        profile: 16i
        count: 3             # lathe-1, lathe-2, lathe-3

Validation problems are reported together as edge.ConfigError, each naming its path in the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from edge import ConfigError
from edge.sim.faults import FaultPlan
from edge.sim.fleet import DEFAULT_ALARM_EVERY, MachineSpec
from edge.sim.profiles import get_profile
from edge.sim.state_program import CycleSpec


class _CycleModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    cut_seconds: float = Field(12.0, gt=0)
    idle_seconds: float = Field(4.0, gt=0.6)
    alarm_every: int = Field(DEFAULT_ALARM_EVERY, ge=0)
    alarm_seconds: float = Field(3.0, gt=0)
    program_number: int = Field(1234, ge=1, le=99999999)


class _MachineModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = ""
    profile: str = "30i"
    count: int = Field(1, ge=1, le=1000)
    timezone: str = "UTC"
    clock_offset: float = 0.0
    cycle: _CycleModel | None = None
    seed: int | None = None
    start_parts: int = Field(0, ge=0)
    param_write_enabled: bool = False
    macros: dict[int, float | None] = Field(default_factory=dict)
    faults: dict[str, Any] = Field(default_factory=dict)

    @field_validator("profile")
    @classmethod
    def _known_profile(cls, value: str) -> str:
        return get_profile(value).name

    @field_validator("timezone")
    @classmethod
    def _known_zone(cls, value: str) -> str:
        try:
            ZoneInfo(value)
        except (ZoneInfoNotFoundError, ValueError):
            raise ValueError(f"unknown time zone {value!r}; expected an IANA name (Europe/Berlin)") from None
        return value

    @field_validator("faults")
    @classmethod
    def _known_faults(cls, value: dict[str, Any]) -> dict[str, Any]:
        FaultPlan().update(value)
        return value


class _ScenarioModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    host: str = "127.0.0.1"
    base_port: int = Field(8193, ge=0, le=65535)
    packed_base_port: int | None = Field(None, ge=0, le=65535)
    admin_port: int | None = Field(None, ge=0, le=65535)
    machines: list[_MachineModel] = Field(min_length=1)


@dataclass
class Scenario:
    """A validated scenario: where to listen and one MachineSpec per machine (counts expanded)."""

    machines: list[MachineSpec]
    host: str = "127.0.0.1"
    base_port: int = 8193
    packed_base_port: int | None = None
    admin_port: int | None = None
    source: str = field(default="scenario")


def parse_scenario(data: Any, source: str = "scenario") -> Scenario:
    """Validate already-parsed YAML/JSON data; ConfigError lists every problem with its path."""
    try:
        model = _ScenarioModel.model_validate(data)
    except ValidationError as exc:
        problems = [f"{'.'.join(str(p) for p in err['loc']) or '(top)'}: {err['msg']}"
                    for err in exc.errors()]
        raise ConfigError(problems, source) from None
    specs: list[MachineSpec] = []
    for entry in model.machines:
        cycle = CycleSpec(**(entry.cycle or _CycleModel.model_validate({})).model_dump())
        for copy in range(entry.count):
            name = entry.name if entry.count == 1 else f"{entry.name or entry.profile}-{copy + 1}"
            specs.append(MachineSpec(
                name=name, profile=entry.profile, timezone=entry.timezone, clock_offset=entry.clock_offset,
                cycle=cycle, seed=entry.seed, start_parts=entry.start_parts,
                param_write_enabled=entry.param_write_enabled, macros=dict(entry.macros),
                faults=dict(entry.faults)))
    return Scenario(specs, model.host, model.base_port, model.packed_base_port, model.admin_port, source)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a YAML scenario file."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError([f"cannot read the file: {exc.strerror}"], source) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError([f"not valid YAML: {exc}"], source) from None
    return parse_scenario(data, source)
