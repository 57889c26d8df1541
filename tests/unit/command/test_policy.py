"""Write policy: master switch, allow-list patterns with bounds, per-machine rate limit."""

from __future__ import annotations

from dataclasses import replace

import pytest

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.limits import check_limits
from edge.command.policy import RateLimiter, authorise
from edge.command.requests import make_op
from edge.command.settings import AllowRule, RateLimit, WritePolicy
from edge.command.target_io import check_param
from edge.focas.model import ParamRecord, ParamType
from edge.focas.targets import MacroTarget, parse_writable


def policy(*rules: AllowRule, enabled: bool = True) -> WritePolicy:
    return WritePolicy(enabled=enabled, allow=rules, rate_limit=RateLimit(max_writes=10, per_s=60.0),
                       reconnect_deadline_s=1.0)


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


def test_bounds_apply_to_the_number_the_pmc_holds() -> None:
    # Bytes read unsigned: -1 would land as 255, so a bounded rule refuses it instead of passing it as -1.
    bounded = policy(AllowRule(target="pmc:R300-R309", max=100))
    assert code("pmc:R300", -1, bounded) is ErrorCode.OUT_OF_BOUNDS
    assert code("pmc:R300-R301", [5, -1], bounded) is ErrorCode.OUT_OF_BOUNDS
    assert code("pmc:R300", 100, bounded) is None
    # Words and longs read signed: 65535 would land as -1, 2^32-1 likewise.
    words = policy(AllowRule(target="pmc:D0-D99", min=-5, max=100))
    assert code("pmc:D0.word", -1, words) is None
    assert code("pmc:D0.word", 65535, words) is ErrorCode.OUT_OF_BOUNDS
    assert code("pmc:D0.long", 2**32 - 1, words) is ErrorCode.OUT_OF_BOUNDS
    assert code("pmc:D0.long", -5, words) is None
    # Without a bound either reading of the width is accepted (the element's bits are the same).
    free = policy(AllowRule(target="pmc:R300-R309"), AllowRule(target="pmc:D0-D99"))
    assert code("pmc:R300", -1, free) is None and code("pmc:D0.word", 65535, free) is None


def test_refusal_names_the_reading_and_the_value_the_cnc_would_hold() -> None:
    with pytest.raises(CommandRefused) as refused:
        authorise(make_op(parse_writable("pmc:R300"), -1), policy(AllowRule(target="pmc:R300-R309", max=100)))
    assert "255" in refused.value.message and "unsigned" in refused.value.message


def param_code(value: int, ptype: ParamType, bounded: bool) -> ErrorCode | None:
    op = replace(make_op(parse_writable("param:1825/1"), value), bounded=bounded)
    try:
        check_param(op, ParamRecord(1825, 1, ptype, (0,)))
    except CommandRefused as exc:
        return exc.code
    return None


def test_parameter_values_are_checked_in_the_reading_the_cnc_reports() -> None:
    assert param_code(2**31, ParamType.TWO_WORD, bounded=False) is ErrorCode.WRONG_TYPE
    assert param_code(-(2**31), ParamType.TWO_WORD, bounded=True) is None
    assert param_code(70000, ParamType.WORD, bounded=False) is ErrorCode.WRONG_TYPE
    # A byte parameter reads signed: 200 lands as -56. Without a bound the bits are what was asked for;
    # under a bound it is refused, as the number checked would not be the number held.
    assert param_code(200, ParamType.BYTE, bounded=False) is None
    assert param_code(200, ParamType.BYTE, bounded=True) is ErrorCode.OUT_OF_BOUNDS
    assert param_code(40000, ParamType.WORD, bounded=True) is ErrorCode.OUT_OF_BOUNDS
    assert param_code(-56, ParamType.BYTE, bounded=True) is None
    assert param_code(255, ParamType.BIT, bounded=True) is None
    assert param_code(-1, ParamType.BIT, bounded=False) is ErrorCode.WRONG_TYPE


def test_authorise_says_whether_a_bound_applied() -> None:
    assert authorise(make_op(parse_writable("param:1825/1"), 5),
                     policy(AllowRule(target="param:1825", max=100))) is True
    assert authorise(make_op(parse_writable("param:1825/1"), 5), policy(AllowRule(target="param:1825"))) is False
