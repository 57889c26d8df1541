"""JSON write requests: every refusal has its code, values fit their target's width, nothing else raises."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.requests import make_op, parse_request, pmc_bytes
from edge.focas.model import PmcType
from edge.focas.targets import MacroTarget, PmcTarget, parse_writable


def item(body: object) -> tuple[ErrorCode | None, object]:
    parsed = parse_request(json.dumps(body).encode(), 4096)
    (first,) = parsed.items
    return (first.refused.code if first.refused else None), (first.op.value if first.op else None)


@pytest.mark.parametrize(("body", "code"), [
    ({"target": "macro:500", "value": "1"}, ErrorCode.WRONG_TYPE),
    ({"target": "macro:500", "value": True}, ErrorCode.WRONG_TYPE),
    ({"target": "macro:500", "value": 3e9}, ErrorCode.WRONG_TYPE),
    ({"target": "macro:500-501", "value": 1}, ErrorCode.WRONG_TYPE),
    ({"target": "pmc:R100", "value": 256}, ErrorCode.WRONG_TYPE),
    ({"target": "pmc:R100", "value": 1.5}, ErrorCode.WRONG_TYPE),
    ({"target": "pmc:R100.word", "value": 70000}, ErrorCode.WRONG_TYPE),
    ({"target": "pmc:R100.3", "value": 2}, ErrorCode.WRONG_TYPE),
    ({"target": "pmc:R100-R101", "value": [1, 2, 3]}, ErrorCode.WRONG_TYPE),
    ({"target": "param:1815/1.3", "value": "on"}, ErrorCode.WRONG_TYPE),
    ({"target": "diag:980", "value": 1}, ErrorCode.INVALID_TARGET),
    ({"target": "pmc:R100.9", "value": 1}, ErrorCode.INVALID_TARGET),
    ({"target": "macro:500"}, ErrorCode.MALFORMED),
    ({"value": 1}, ErrorCode.MALFORMED),
    ({"target": "macro:500", "value": 1, "extra": 1}, ErrorCode.MALFORMED),
    ({"target": "macro:500", "value": {"a": 1}}, ErrorCode.WRONG_TYPE),
    (["macro:500"], ErrorCode.MALFORMED),
])
def test_refusals_carry_their_code(body: object, code: ErrorCode) -> None:
    first = parse_request(json.dumps(body).encode(), 4096).items[0]
    assert first.op is None and first.refused is not None
    assert first.refused.code is code, first.refused.message


def test_values_are_normalised_per_target() -> None:
    assert item({"target": "macro:500", "value": 2}) == (None, 2.0)
    assert item({"target": "pmc:R100", "value": 255}) == (None, (255,))
    assert item({"target": "pmc:R100", "value": -1}) == (None, (-1,))
    assert item({"target": "pmc:R100-R103.word", "value": [1, -2]}) == (None, (1, -2))
    assert item({"target": "pmc:R100.3", "value": 1}) == (None, True)
    assert item({"target": "param:1825/1", "value": 3000.0}) == (None, 3000.0)


def test_request_level_refusals() -> None:
    with pytest.raises(CommandRefused) as too_big:
        parse_request(b"{" + b" " * 5000 + b"}", 4096)
    assert too_big.value.code is ErrorCode.PAYLOAD_TOO_LARGE
    for bad in (b"{", b"\xff\xfe", b"[]"):
        with pytest.raises(CommandRefused) as malformed:
            parse_request(bad, 4096)
        assert malformed.value.code is ErrorCode.MALFORMED


def test_list_keeps_ids_and_order() -> None:
    parsed = parse_request(json.dumps([{"id": "a", "target": "macro:500", "value": 1},
                                       {"id": 2, "target": "nope", "value": 1}]).encode(), 4096)
    assert parsed.is_list and [i.id for i in parsed.items] == ["a", 2]
    assert parsed.items[1].refused is not None and parsed.items[1].refused.code is ErrorCode.INVALID_TARGET


def test_pmc_bytes_big_endian_both_signs() -> None:
    target = parse_writable("pmc:D0-D3.word")
    assert isinstance(target, PmcTarget)
    assert pmc_bytes(target, (600, -1)) == b"\x02\x58\xff\xff"
    assert pmc_bytes(PmcTarget("R", 0, 3, PmcType.FLOAT), (1.0,)) == b"\x3f\x80\x00\x00"


def test_make_op_rejects_what_does_not_fit() -> None:
    with pytest.raises(ValueError, match="does not fit a byte"):
        make_op(PmcTarget("R", 0, 0), 300)
    assert make_op(MacroTarget(500, 500), 1.25).value == 1.25


json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                           lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=6), inner, max_size=4), max_leaves=12)
requests = st.fixed_dictionaries({}, optional={
    "id": st.text(max_size=4) | st.integers(), "value": json_values,
    "target": st.sampled_from(["macro:500", "pmc:R100", "pmc:R100.3", "pmc:D0-D7.long", "param:1815/1.3",
                               "param:1825/1", "x", ""]) | st.text(max_size=12)}) | json_values


@given(requests)
def test_any_json_is_an_op_or_a_coded_refusal(document: object) -> None:
    try:
        payload = json.dumps(document).encode()
    except ValueError:
        return
    try:
        parsed = parse_request(payload, 1 << 20)
    except CommandRefused as exc:
        assert exc.code in (ErrorCode.MALFORMED, ErrorCode.PAYLOAD_TOO_LARGE)
        return
    for entry in parsed.items:
        assert (entry.op is None) != (entry.refused is None)


@given(st.binary(max_size=64))
def test_any_bytes_never_raise_anything_else(payload: bytes) -> None:
    try:
        parsed = parse_request(payload, 4096)
    except CommandRefused as exc:
        assert exc.code in (ErrorCode.MALFORMED, ErrorCode.PAYLOAD_TOO_LARGE)
        return
    assert parsed.items


@pytest.mark.parametrize("depth", [40, 2000, 100_000])
def test_json_nested_deeper_than_the_limit_is_malformed(depth: int) -> None:
    # ~1000 levels used to raise RecursionError out of the parser: no reply, no audit line.
    for payload in (b"[" * depth + b"]" * depth, b'{"value":' * depth + b"1" + b"}" * depth):
        with pytest.raises(CommandRefused) as malformed:
            parse_request(payload, 10 * depth + 10)
        assert malformed.value.code is ErrorCode.MALFORMED
        assert "nested" in malformed.value.message


def test_brackets_inside_strings_do_not_count_as_nesting() -> None:
    (first,) = parse_request(json.dumps({"id": "[[[[" * 50, "target": "macro:500", "value": 1}).encode(),
                             4096).items
    assert first.refused is None and first.id == "[[[[" * 50


@pytest.mark.parametrize(("target", "value"), [
    ("macro:500", "12"), ("macro:500", None), ("pmc:R100", "x"), ("param:1825/1", "1"), ("pmc:R100-R101", ["a", 1]),
])
def test_a_number_target_given_something_else_says_expected_a_number(target: str, value: object) -> None:
    (first,) = parse_request(json.dumps({"target": target, "value": value}).encode(), 4096).items
    assert first.refused is not None and first.refused.code is ErrorCode.WRONG_TYPE
    assert "expected a number" in first.refused.message and "boolean" not in first.refused.message


# ---- the CNC path of a write: `@N` in the target or a "path" field ----------------------------------------


@pytest.mark.parametrize("body", [
    {"target": "macro:500@2", "value": 1.5},
    {"target": "macro:500", "path": 2, "value": 1.5},
    {"target": "macro:500@2", "path": 2, "value": 1.5},
])
def test_a_write_names_its_path_in_the_target_or_a_path_field(body: dict[str, object]) -> None:
    (item,) = parse_request(json.dumps(body).encode(), 4096).items
    assert item.refused is None and item.op is not None
    assert (item.op.target, item.op.path, item.op.text) == (MacroTarget(500, 500), 2, "macro:500@2")


def test_a_write_without_a_path_names_none() -> None:
    (item,) = parse_request(b'{"target": "pmc:R100.3", "value": 1}', 4096).items
    assert item.op is not None and item.op.path is None and item.op.text == "pmc:R100.3"


@pytest.mark.parametrize(("body", "code", "why"), [
    ({"target": "macro:500@2", "path": 3, "value": 1}, ErrorCode.MALFORMED, "names path 2 but path is 3"),
    ({"target": "macro:500@11", "value": 1}, ErrorCode.INVALID_TARGET, "path 11 is not 1..10"),
    ({"target": "diag:980@2", "value": 1}, ErrorCode.INVALID_TARGET, "read-only"),
    ({"target": "macro:500", "path": 0, "value": 1}, ErrorCode.MALFORMED, "path"),
    ({"target": "macro:500", "path": "2", "value": 1}, ErrorCode.MALFORMED, "path"),
])
def test_a_bad_or_conflicting_path_is_refused(body: dict[str, object], code: ErrorCode, why: str) -> None:
    (item,) = parse_request(json.dumps(body).encode(), 4096).items
    assert item.op is None and item.refused is not None
    assert item.refused.code is code and why in item.refused.message


# ---- fuzz: any JSON document or bytes parse or are refused, nothing else ----------------------------------
fuzz_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=12)),
    lambda children: st.one_of(st.lists(children, max_size=4),
                               st.dictionaries(st.text(max_size=8), children, max_size=4)),
    max_leaves=12)
fuzz_targets = st.one_of(st.sampled_from(["macro:500", "pmc:R100", "pmc:R100.3", "pmc:D2204:word", "param:1815",
                                          "param:1815:1", "macro:", "pmc:Z9", ""]), st.text(max_size=16))
fuzz_requests = st.one_of(
    fuzz_values,
    st.fixed_dictionaries({"target": fuzz_targets, "value": fuzz_values}, optional={"id": fuzz_values}),
    st.lists(st.fixed_dictionaries({"target": fuzz_targets, "value": fuzz_values}), max_size=3),
)


@given(fuzz_requests)
def test_fuzz_json_write_requests_parse_or_refuse(document: object) -> None:
    import json

    payload = json.dumps(document).encode()
    try:
        parsed = parse_request(payload, 4096)
    except CommandRefused:
        return
    for item in parsed.items:
        assert (item.op is None) != (item.refused is None), item


@given(st.binary(max_size=300))
def test_fuzz_json_write_request_bytes_parse_or_refuse(payload: bytes) -> None:
    try:
        parsed = parse_request(payload, 256)
    except CommandRefused:
        return
    assert all((i.op is None) != (i.refused is None) for i in parsed.items)
