"""Composite reads degrade part by part, from answers recorded off the simulator (one part refused)."""

from __future__ import annotations

from typing import Any

import pytest

from edge.cli.named_reads import NAMED_READS
from edge.cli.read import ReadPlan, _outcome
from edge.focas.errors import cnc_error
from edge.focas.model import ExecProgram, ProgramNumbers

REFUSED = cnc_error(1, "recorded")  # EW_FUNC


def plan(name: str) -> ReadPlan:
    named = NAMED_READS[name]
    return ReadPlan(name, named.items, named.shape, named.parts)


# The answers a simulated 30i gave, in item order (recorded once; the shapes the decoders return).
RECORDED: dict[str, list[Any]] = {
    "program": [ProgramNumbers(running=1234, main=1234), 120, ExecProgram(1234, "O1234"), "//CNC_MEM/USER/PATH1/O1234"],
    "loads": [["X", "Z", "C"], [12.0, 8.0, 0.0], ["S1", "S2"], [40.0, 0.0]],
    "speeds": [1500.0, 8000.0],
    "axes": [["X", "Z", "C"], 3],
}


def test_every_multi_item_read_has_every_item_in_a_part() -> None:
    """A composite never fails whole because of one function: each of its items belongs to a part."""
    for name, named in NAMED_READS.items():
        if len(named.items) > 1:
            covered = {i for indices in named.parts.values() for i in indices}
            assert covered == set(range(len(named.items))), name


@pytest.mark.parametrize(("name", "refuse", "part", "missing"), [
    ("program", 2, "name", {"name"}),
    ("program", 0, "number", {"running", "main"}),
    ("loads", 2, "spindle", {"spindle"}),  # spindle names refused, as on a 31i lathe
    ("loads", 0, "servo", {"servo"}),  # axis names refused: the servo loads cannot be named
    ("speeds", 0, "feed", {"feed"}),
    ("axes", 1, "controlled", {"controlled"}),
])
def test_one_refused_item_leaves_out_its_part_only(name: str, refuse: int, part: str, missing: set[str]) -> None:
    whole = _outcome(plan(name), list(RECORDED[name]))
    answers = list(RECORDED[name])
    answers[refuse] = REFUSED
    outcome = _outcome(plan(name), answers)
    assert outcome.error is None
    assert [p for p, _ in outcome.part_errors] == [part]
    assert isinstance(whole.value, dict) and isinstance(outcome.value, dict)
    assert set(outcome.value) == set(whole.value) - missing


def test_every_part_refused_fails_the_item_naming_each() -> None:
    outcome = _outcome(plan("program"), [REFUSED] * 4)
    assert outcome.error is REFUSED
    assert [p for p, _ in outcome.part_errors] == ["number", "sequence", "name", "path"]
