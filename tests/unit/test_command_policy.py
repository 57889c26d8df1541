"""Write policy: master switch, allow-list patterns with bounds, per-machine rate limit."""

from __future__ import annotations

import pytest

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.limits import check_limits
from edge.command.policy import RateLimiter, authorise
from edge.command.requests import make_op
from edge.config import AllowRule, RateLimit, WritePolicy
from edge.targets import MacroTarget, parse_writable


def policy(*rules: AllowRule, enabled: bool = True) -> WritePolicy:
    return WritePolicy(enabled=enabled, allow=rules, rate_limit=RateLimit(), reconnect_deadline_s=1.0,
                       max_payload_bytes=4096)


def code(target: str, value: object, p: WritePolicy) -> ErrorCode | None:
    try:
        authorise(make_op(parse_writable(target), value), p)
    except CommandRefused as exc:
        return exc.code
    return None


def test_disabled_refuses_everything() -> None:
    assert code("macro:500", 1, policy(AllowRule(target="macro:500-599"), enabled=False)) is ErrorCode.DISABLED


def test_patterns_and_bounds() -> None:
    p = policy(AllowRule(target="macro:500-599", min=0, max=10), AllowRule(target="pmc:R100-R199"),
               AllowRule(target="param:1815/1.3"))
    assert code("macro:500", 10, p) is None
    assert code("macro:500", 10.5, p) is ErrorCode.OUT_OF_BOUNDS
    assert code("macro:600", 1, p) is ErrorCode.NOT_ALLOWED
    assert code("pmc:R199", 255, p) is None
    assert code("pmc:R198-R201", [1, 2, 3, 4], p) is ErrorCode.NOT_ALLOWED  # leaves the range
    assert code("param:1815/1.3", True, p) is None
    assert code("param:1815/1.4", True, p) is ErrorCode.NOT_ALLOWED
    assert code("param:1815/1", 1, p) is ErrorCode.NOT_ALLOWED


def test_any_covering_rule_may_accept_the_value() -> None:
    p = policy(AllowRule(target="macro:500-599", max=10), AllowRule(target="macro:550", min=100))
    assert code("macro:550", 150, p) is None
    assert code("macro:551", 150, p) is ErrorCode.OUT_OF_BOUNDS
    assert code("pmc:R100-R101", [1, 2], policy(AllowRule(target="pmc:R100-R101", max=1))) \
        is ErrorCode.OUT_OF_BOUNDS


def test_rate_limit_is_a_sliding_window_per_machine() -> None:
    now = [0.0]
    limiter = RateLimiter(clock=lambda: now[0])
    limit = RateLimit(max_writes=3, per_s=10)
    limiter.admit("m1", 2, limit)
    with pytest.raises(CommandRefused) as refused:
        limiter.admit("m1", 2, limit)  # all or nothing
    assert refused.value.code is ErrorCode.RATE_LIMITED
    limiter.admit("m1", 1, limit)
    limiter.admit("m2", 3, limit)
    now[0] = 10.0
    limiter.admit("m1", 3, limit)


def test_limits_refuse_macros_that_are_not_there() -> None:
    for number in (0, 1, 33, 50):
        with pytest.raises(CommandRefused) as refused:
            check_limits(MacroTarget(number, number), None)
        assert refused.value.code is ErrorCode.OUT_OF_RANGE
    check_limits(MacroTarget(100, 100), None)
    check_limits(MacroTarget(2001, 2001), None)
