"""Whether a validated write may go to a machine: the master switch, the allow-list with its bounds,
and the per-machine rate limit. Pure decisions; nothing here talks to a CNC.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.requests import WriteOp
from edge.command.settings import AllowRule, RateLimit, WritePolicy
from edge.command.signedness import PMC_READINGS, Reading
from edge.focas.targets import PmcTarget


def authorise(op: WriteOp, policy: WritePolicy) -> bool:
    """Raise CommandRefused (disabled, not_allowed, out_of_bounds) unless the policy allows `op`.

    Bounds are checked against the number the CNC will hold (edge.command.signedness); a value given in
    the other reading of its width is refused by a bounded rule. Returns whether the rule that accepted
    `op` has a bound (a parameter's reading is known only after its type is read: the executor checks).
    """
    if not policy.enabled:
        raise CommandRefused(ErrorCode.DISABLED, "writes are disabled for this machine "
                             "(writes.enabled is false, or the machine's writes.enabled)")
    covering = [rule for rule in policy.allow if rule.pattern.covers(op.target)]
    if not covering:
        raise CommandRefused(ErrorCode.NOT_ALLOWED, f"{op.target} is not covered by any writes.allow pattern")
    if any(rule.min is None and rule.max is None for rule in covering):
        return False
    values = numeric_values(op)
    reading = _pmc_reading(op)
    other = reading is not None and any(reading.is_other(int(v)) for v in values)
    held = tuple(float(reading.held(int(v))) for v in values) if reading is not None else values
    if not other and any(all(_within(rule, v) for v in held) for rule in covering):
        return True
    bounds = ", ".join(_describe(rule) for rule in covering)
    shown = _shown(values)
    if other:
        assert reading is not None and isinstance(op.target, PmcTarget)
        raise CommandRefused(ErrorCode.OUT_OF_BOUNDS, f"{op.target}: value {shown} would be held as {_shown(held)} "
                             f"(a {op.target.data_type.name.lower()} reads {reading.describe()}); a bounded rule "
                             f"({bounds}) takes values in that reading only")
    raise CommandRefused(ErrorCode.OUT_OF_BOUNDS, f"{op.target}: value {shown} is outside {bounds}")


def numeric_values(op: WriteOp) -> tuple[float, ...]:
    """The value(s) a bound is checked against (a bit counts as 0 or 1)."""
    if isinstance(op.value, tuple):
        return tuple(float(v) for v in op.value)
    return (float(op.value),)


def _pmc_reading(op: WriteOp) -> Reading | None:
    target = op.target
    if isinstance(target, PmcTarget) and target.bit is None:
        return PMC_READINGS.get(target.data_type)
    return None


def _shown(values: tuple[float, ...]) -> object:
    numbers = [int(v) if v.is_integer() else v for v in values]
    return numbers[0] if len(numbers) == 1 else numbers


def _within(rule: AllowRule, value: float) -> bool:
    return (rule.min is None or value >= rule.min) and (rule.max is None or value <= rule.max)


def _describe(rule: AllowRule) -> str:
    low = "-inf" if rule.min is None else f"{rule.min:g}"
    high = "+inf" if rule.max is None else f"{rule.max:g}"
    return f"{rule.target} [{low}..{high}]"


class RateLimiter:
    """At most `max_writes` writes per `per_s` seconds per machine (sliding window of admissions)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._admitted: dict[str, deque[float]] = {}

    def admit(self, machine_id: str, count: int, limit: RateLimit) -> None:
        """Reserve `count` writes now, or raise CommandRefused(rate_limited) and reserve none."""
        now = self._clock()
        window = self._admitted.setdefault(machine_id, deque())
        while window and window[0] <= now - limit.per_s:
            window.popleft()
        if len(window) + count > limit.max_writes:
            retry = (window[0] + limit.per_s - now) if window else limit.per_s
            raise CommandRefused(ErrorCode.RATE_LIMITED,
                                 f"{len(window)} write(s) in the last {limit.per_s:g} s, {count} more would pass "
                                 f"the limit of {limit.max_writes}; retry in {max(retry, 0.0):.1f} s")
        window.extend([now] * count)
