from __future__ import annotations

import contextlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.focas.model import PmcType
from edge.focas.targets import (
    DiagTarget,
    MacroTarget,
    NamedTarget,
    ParamTarget,
    PmcTarget,
    TargetError,
    TargetPattern,
    parse_assignment,
    parse_target,
    parse_writable,
    split_path,
)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("macro:500", MacroTarget(500, 500)),
        ("macro:500-505", MacroTarget(500, 505)),
        ("pmc:R100", PmcTarget("R", 100, 100)),
        ("pmc:R100-R103", PmcTarget("R", 100, 103)),
        ("pmc:r100-103", PmcTarget("R", 100, 103)),
        ("pmc:R100.3", PmcTarget("R", 100, 100, PmcType.BYTE, 3)),
        ("pmc:D2204.word", PmcTarget("D", 2204, 2205, PmcType.WORD)),
        ("pmc:D2204-D2207.word", PmcTarget("D", 2204, 2207, PmcType.WORD)),
        ("pmc:D8.long", PmcTarget("D", 8, 11, PmcType.LONG)),
        ("pmc:D8.double", PmcTarget("D", 8, 15, PmcType.DOUBLE)),
        ("param:6711", ParamTarget(6711, 6711)),
        ("param:1815/1", ParamTarget(1815, 1815, 1)),
        ("param:1815/0.3", ParamTarget(1815, 1815, 0, 3)),
        ("param:6711.2", ParamTarget(6711, 6711, 0, 2)),
        ("diag:980-981/1", DiagTarget(980, 981, 1)),
        ("param:1850/all", ParamTarget(1850, 1850, -1)),
        ("param:1815/ALL.4", ParamTarget(1815, 1815, -1, 4)),
        ("diag:308-309/all", DiagTarget(308, 309, -1)),
        ("sysinfo", NamedTarget("sysinfo")),
        (" Clock ", NamedTarget("clock")),
        ("positions", NamedTarget("positions")),
    ],
)
def test_parses(text: str, expected: object) -> None:
    assert parse_target(text) == expected


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("macro:505-500", "end 500 before start 505"),
        ("macro:abc", "expected macro:N"),
        ("pmc:Q100", "unknown PMC area 'Q'"),
        ("pmc:R100.8", "bit 8 is not 0..7"),
        ("pmc:R100-R101.3", "a bit addresses one byte"),
        ("pmc:R100-D101", "one area"),
        ("pmc:D2204-D2206.word", "3 bytes, not a whole number of word"),
        ("pmc:D2204.nibble", "unknown suffix .nibble"),
        ("param:1815/33", "axis 33"),
        ("param:1815-1816.1", "a bit addresses one parameter"),
        ("diag:980.1", "no bit form"),
        ("foo:1", "unknown kind 'foo'"),
        ("positionz", "expected KIND:ADDRESS"),
        ("macro:100000", "beyond 99999"),
        ("pmc:R65535.word", "beyond 65535"),
    ],
)
def test_rejects_with_reason(text: str, fragment: str) -> None:
    with pytest.raises(TargetError) as info:
        parse_target(text)
    assert fragment in str(info.value)
    assert repr(text) in str(info.value) or text.strip() in str(info.value)


def test_target_error_is_value_error() -> None:
    assert issubclass(TargetError, ValueError)


@pytest.mark.parametrize("text", ["diag:980", "status", "clock"])
def test_read_only_targets_are_not_writable(text: str) -> None:
    with pytest.raises(TargetError, match="read-only"):
        parse_writable(text)


def test_all_axes_round_trips_and_is_read_only_for_parameters() -> None:
    assert str(parse_target("param:1850/all")) == "param:1850/all"
    assert str(parse_target("diag:308-309/all")) == "diag:308-309/all"
    with pytest.raises(TargetError, match="names one axis"):
        parse_writable("param:1850/all")


def test_assignment_splits_target_and_value() -> None:
    assert parse_assignment("pmc:R100.3=1") == (PmcTarget("R", 100, 100, PmcType.BYTE, 3), "1")
    with pytest.raises(TargetError, match="TARGET=VALUE"):
        parse_assignment("macro:500")
    with pytest.raises(TargetError, match="TARGET=VALUE"):
        parse_assignment("macro:500=")


@pytest.mark.parametrize(
    "text",
    ["macro:500", "macro:500-505", "pmc:R100", "pmc:R100-R103", "pmc:R100.3", "pmc:D2204.word",
     "pmc:D2204-D2207.word", "param:6711", "param:1815/1", "param:1815/0.3", "diag:980-981/1", "alarms"],
)
def test_str_round_trips(text: str) -> None:
    target = parse_target(text)
    assert str(target) == text
    assert parse_target(str(target)) == target


@pytest.mark.parametrize(
    ("pattern", "target", "covered"),
    [
        ("macro:500-599", "macro:520", True),
        ("macro:500-599", "macro:599-600", False),
        ("macro:500-599", "pmc:R500", False),
        ("pmc:R100-R199", "pmc:R150.3", True),
        ("pmc:R100-R199", "pmc:R198.word", True),
        ("pmc:R100-R199", "pmc:R199.word", False),
        ("pmc:R100-R199", "pmc:D150", False),
        ("pmc:R100.3", "pmc:R100.3", True),
        ("pmc:R100.3", "pmc:R100.4", False),
        ("pmc:R100.3", "pmc:R100", False),
        ("param:1815", "param:1815/2", True),
        ("param:1815", "param:1815/0.3", True),
        ("param:1815/1", "param:1815/2", False),
        ("param:1815/1", "param:1815/1", True),
        ("param:1815/0.3", "param:1815/0.3", True),
        ("param:1815/0.3", "param:1815/0.4", False),
        ("param:1815/0.3", "param:1815/1.3", False),
        ("param:6711", "param:6712", False),
    ],
)
def test_pattern_coverage(pattern: str, target: str, covered: bool) -> None:
    assert TargetPattern.parse(pattern).covers(parse_target(target)) is covered


@given(st.text(max_size=40))
def test_arbitrary_strings_only_raise_target_error(text: str) -> None:
    with contextlib.suppress(TargetError):
        parse_target(text)


_grammarish = st.from_regex(
    r"(macro|pmc|param|diag|MACRO|x)?:?[A-Za-z]?\d{0,7}(-[A-Za-z]?\d{0,7})?(/\d{0,3})?(\.(\d{1,2}|word|long|x))?",
    fullmatch=True)


@given(_grammarish)
def test_near_grammar_strings_parse_or_raise_target_error(text: str) -> None:
    try:
        target = parse_target(text)
    except TargetError:
        return
    assert parse_target(str(target)) == target


# ---- `@N`: the CNC path a target names ------------------------------------------------------------------


@pytest.mark.parametrize(("text", "bare", "path"), [
    ("macro:500@2", "macro:500", 2),
    ("pmc:R100.3@2", "pmc:R100.3", 2),
    ("param:1825/1@2", "param:1825/1", 2),
    ("program@10", "program", 10),
    ("macro:500 @ 2", "macro:500", 2),
    ("macro:500", "macro:500", None),
])
def test_split_path_takes_the_path_suffix_off(text: str, bare: str, path: int | None) -> None:
    assert split_path(text) == (bare, path)
    parse_target(split_path(text)[0])  # what is left is the usual grammar


@pytest.mark.parametrize(("text", "why"), [
    ("macro:500@0", "path 0 is not 1..10"),
    ("macro:500@11", "path 11 is not 1..10"),
    ("macro:500@two", "expected TARGET@PATH"),
    ("macro:500@2@3", "expected TARGET@PATH"),
    ("macro:500@", "expected TARGET@PATH"),
])
def test_a_bad_path_suffix_is_refused_naming_the_target(text: str, why: str) -> None:
    with pytest.raises(TargetError, match=why) as caught:
        split_path(text)
    assert repr(text) in str(caught.value)


@given(st.sampled_from(["macro:500", "pmc:R100.3", "pmc:D2204-D2207.word", "param:1825/1", "param:6711/0.2",
                        "diag:980", "program"]), st.integers(1, 10))
def test_any_target_with_a_path_suffix_splits_back(text: str, path: int) -> None:
    assert split_path(f"{text}@{path}") == (text, path)
    assert str(parse_target(text)) == str(parse_target(split_path(f"{text}@{path}")[0]))
