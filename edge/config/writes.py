"""`writes:` remote writes: allow rules (target patterns with value bounds), the rate limit, and the
effective WritePolicy of one machine (Config.write_policy joins the global rules and the machine's own;
the global `enabled` is the master switch, off by default).
"""

from __future__ import annotations

from pydantic import ByteSize, Field, ValidationInfo, field_validator

from edge.config.fields import Duration, _Model
from edge.focas.targets import TargetError, TargetPattern


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


class AuditConfig(_Model):
    """`<state_dir>/write-audit.jsonl` is rotated by the daemon past max_bytes, keeping `keep` older files."""

    max_bytes: ByteSize = Field(default=ByteSize(10 * 1024 * 1024), ge=64 * 1024)
    keep: int = Field(default=5, ge=1, le=100)


class WritesConfig(_Model):
    enabled: bool = False
    allow: list[AllowRule] = Field(default_factory=list)
    rate_limit: RateLimit = Field(default_factory=RateLimit)
    reconnect_deadline_s: Duration = 10.0
    max_payload_bytes: int = Field(default=4096, ge=64, le=1_048_576)  # a JSON request or a DCMD
    audit: AuditConfig = Field(default_factory=AuditConfig)


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
