"""What the write path needs to know, as plain frozen values (edge.service.settings builds them from the config).

A machine's effective write policy is the global `writes` section merged with the machine's own (the global
`enabled` is the master switch); the merge is done once, in edge.service.settings, and the command layer
only reads the result.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from edge.collect import MachineSettings
from edge.focas.targets import TargetPattern


@dataclass(frozen=True, slots=True)
class AllowRule:
    """One allowed write target pattern, with optional value bounds (inclusive)."""

    target: str  # as written in the config (refusals quote it)
    min: float | None = None
    max: float | None = None
    pattern: TargetPattern = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "pattern", TargetPattern.parse(self.target))


@dataclass(frozen=True, slots=True)
class RateLimit:
    """At most max_writes writes per `per_s` seconds, per machine."""

    max_writes: int
    per_s: float


@dataclass(frozen=True, slots=True)
class WritePolicy:
    """The effective write policy of one machine: global rules plus the machine's own."""

    enabled: bool
    allow: tuple[AllowRule, ...]
    rate_limit: RateLimit
    reconnect_deadline_s: float  # a write waits this long for a lost session to come back


@dataclass(frozen=True, slots=True)
class CommandSettings:
    """Every device that can take writes, with its policy, and what applies to all of them."""

    state_dir: Path  # the audit log lives here
    max_payload_bytes: int
    machines: Mapping[str, MachineSettings]  # by device id: path routing, and the plan before a poller has one
    policies: Mapping[str, WritePolicy]  # by device id, the same keys
    audit_max_bytes: int = 10 * 1024 * 1024  # write-audit.jsonl is rotated past this size ...
    audit_keep: int = 5  # ... keeping this many older files (.1 .. .keep)
