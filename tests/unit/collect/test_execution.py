"""The status word -> MES vocabulary table, row by row, and what docs/topics.md says about it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from edge.collect.execution import (
    CONTROLLER_MODE_TABLE,
    EXECUTION_TABLE,
    UTILISATION_STATES,
    ExecutionRow,
    derive,
    execution_of,
)
from edge.collect.plan import STATUS_METRICS, Group, PlannedRead, metric_values
from edge.focas import items as it
from edge.focas.model import StatInfo

TOPICS_MD = Path(__file__).resolve().parents[3] / "docs" / "topics.md"


def word(aut: int = 1, run: int = 0, motion: int = 0, mstb: int = 0, emergency: int = 0, alarm: int = 0) -> StatInfo:
    return StatInfo(aut, run, motion, mstb, emergency, alarm, 0)


# One status word per row of EXECUTION_TABLE, in table order: (word, Execution, utilisation counts it as).
ROW_EXAMPLES: list[tuple[StatInfo, str, str]] = [
    (word(run=0, emergency=1), "STOPPED", "EMERGENCY"),
    (word(run=0, alarm=1), "STOPPED", "ALARM"),
    (word(run=3, motion=0, mstb=1), "WAIT", "WAIT"),
    (word(run=3, motion=1), "ACTIVE", "ACTIVE"),
    (word(run=4, motion=1), "ACTIVE", "ACTIVE"),
    (word(run=2), "FEED_HOLD", "FEED_HOLD"),
    (word(run=1), "INTERRUPTED", "INTERRUPTED"),
    (word(run=0), "READY", "READY"),
    (word(run=9), "UNAVAILABLE", "UNKNOWN"),
]


def first_matching_row(stat: StatInfo) -> ExecutionRow:
    return next(row for row in EXECUTION_TABLE if row.matches(stat))


def test_every_row_has_an_example_that_it_decides() -> None:
    """Each example is decided by its own row (not an earlier one), so every row is exercised."""
    assert len(ROW_EXAMPLES) == len(EXECUTION_TABLE)
    for row, (stat, execution, counts_as) in zip(EXECUTION_TABLE, ROW_EXAMPLES, strict=True):
        assert first_matching_row(stat) is row, f"{stat} is decided by another row than {row}"
        assert execution_of(stat) == row.execution == execution
        assert derive(stat).counts_as == counts_as
        assert row.evidence, f"row {row} says no evidence"


@pytest.mark.parametrize(("stat", "execution", "counts_as"), [
    (word(run=3, motion=2), "ACTIVE", "ACTIVE"),  # a dwell is part of the program
    (word(run=3, motion=0), "ACTIVE", "ACTIVE"),  # START without motion: computing, spindle coming up
    (word(run=3, motion=1, alarm=1), "ACTIVE", "ALARM"),  # an alarm that did not stop the program still counts
    (word(run=2, alarm=8), "FEED_HOLD", "ALARM"),  # PMC alarm while held
    (word(run=1, alarm=2), "INTERRUPTED", "INTERRUPTED"),  # battery low is a warning, not an alarm
    (word(run=3, motion=1, emergency=1), "STOPPED", "EMERGENCY"),  # emergency wins over everything
    (word(run=0, emergency=2), "READY", "READY"),  # emergency 2 is the RESET signal, not an emergency stop
])
def test_precedence_between_rows(stat: StatInfo, execution: str, counts_as: str) -> None:
    derived = derive(stat)
    assert (derived.execution, derived.counts_as) == (execution, counts_as)


@pytest.mark.parametrize(("aut", "mode"), [
    (0, "MANUAL_DATA_INPUT"), (1, "AUTOMATIC"), (2, "UNAVAILABLE"), (3, "EDIT"), (4, "MANUAL"), (5, "MANUAL"),
    (6, "MANUAL"), (7, "MANUAL"), (8, "MANUAL"), (9, "MANUAL"), (10, "AUTOMATIC"), (42, "UNAVAILABLE"),
])
def test_controller_mode_of_every_aut_code(aut: int, mode: str) -> None:
    assert derive(word(aut=aut)).controller_mode == mode


def test_the_status_read_publishes_execution_and_controller_mode() -> None:
    status = PlannedRead(Group.STATUS, it.ReadStatus(), tuple(spec for spec, _ in STATUS_METRICS))
    values = {spec.name: value for spec, value in metric_values(status, word(aut=0, run=2))}
    assert values["Status/Execution"] == "FEED_HOLD" and values["Status/ControllerMode"] == "MANUAL_DATA_INPUT"
    assert values["Status/Run"] == "HOLD"  # the raw word stays published beside it


def test_utilisation_states_are_what_the_table_can_produce_plus_the_gateways_own() -> None:
    produced = {execution_of(stat) for stat, _, _ in ROW_EXAMPLES} - {"UNAVAILABLE"}
    assert set(UTILISATION_STATES) == produced | {"ALARM", "EMERGENCY", "OFFLINE", "UNKNOWN"}


def test_docs_print_the_same_table() -> None:
    """docs/topics.md "Derived state" lists each row's Execution in table order, and every ControllerMode."""
    text = TOPICS_MD.read_text()
    section = text.split("### Derived state", 1)[1].split("\n### ", 1)[0]
    documented = re.findall(r"^\| \d+ \|[^|]*\|\s*`([A-Z_]+)`", section, flags=re.MULTILINE)
    assert documented == [row.execution for row in EXECUTION_TABLE]
    for mode in set(CONTROLLER_MODE_TABLE.values()):
        assert f"`{mode}`" in section
