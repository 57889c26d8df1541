"""`poll:`: periods, macro and PMC ranges, numbered reads, and the errors of each."""

from __future__ import annotations

import textwrap

import pytest

from edge.focas.model import PmcType
from tests.unit.config.minimal import MINIMAL, parse, problems_of


def _machine_with_poll(poll: str) -> str:
    return MINIMAL + "    poll:\n" + textwrap.indent(textwrap.dedent(poll), "      ")


def test_poll_plan_forms() -> None:
    config = parse(_machine_with_poll("""
        periods: {status: 100ms, macros: 2, pmc: 1.5s, params: 1m, diags: 1h}
        macros: [500, "510-512", {first: 600, last: 601, name_prefix: Tool/Life, deadband: 0.5}]
        pmc:
          - {area: D, range: D2204-D2207, data_type: word, name: Overrides}
          - {area: R, range: 100-101}
          - {area: r, start: 10, end: 13, data_type: long}
        params: [6712, {number: 1815, axis: 2}]
        diags: [{number: 980, axis: 1, name: Servo/Error}]
    """))
    poll = config.machines[0].poll
    assert (poll.periods.status, poll.periods.macros, poll.periods.pmc) == (0.1, 2.0, 1.5)
    assert (poll.periods.params, poll.periods.diags) == (60.0, 3600.0)
    assert [list(m.numbers) for m in poll.macros] == [[500], [510, 511, 512], [600, 601]]
    assert poll.macros[2].metric_name(601) == "Tool/Life/601"
    word = poll.pmc[0].target
    assert (word.area, word.start, word.end, word.data_type) == ("D", 2204, 2207, PmcType.WORD)
    assert poll.pmc[0].addresses() == [2204, 2206]
    assert poll.pmc[0].metric_name(2206) == "Overrides/D2206"
    assert poll.pmc[1].metric_name(101) == "PMC/R101"
    assert poll.pmc[2].target.end == 13 and poll.pmc[2].addresses() == [10]
    assert poll.params[1].metric_name("Param") == "Param/1815/2"
    assert poll.diags[0].metric_name("Diag") == "Servo/Error"


def test_numbered_reads_for_all_axes() -> None:
    config = parse(_machine_with_poll("""
        params: [{number: 1850, axis: all}]
        diags: [{number: 308, axis: ALL, name: Servo/Temperature}]
    """))
    poll = config.machines[0].poll
    assert (poll.params[0].axis, poll.diags[0].axis) == (-1, -1)
    assert poll.params[0].metric_name("Param") == "Param/1850"
    assert poll.diags[0].metric_name("Diag") == "Servo/Temperature"


@pytest.mark.parametrize(
    ("poll", "expected"),
    [
        ("pmc: [{range: D2204-D2206, data_type: word}]",
         "machines[0].poll.pmc[0].range: D2204-D2206 is 3 bytes, not a whole number of word (2-byte) elements"),
        ("pmc: [{area: R, start: 5, end: 1}]", "machines[0].poll.pmc[0].end: end 1 before start 5"),
        ("pmc: [{start: 5}]", "machines[0].poll.pmc[0].area: required with start/end"),
        ("pmc: [{area: R}]", "machines[0].poll.pmc[0].range: required (e.g. range: R100-R103"),
        ("pmc: [{area: R, range: D1}]", "machines[0].poll.pmc[0].range: range 'D1' is in area D, but area is R"),
        ("pmc: [{range: R1, data_type: nibble}]", "machines[0].poll.pmc[0].data_type: "),
        ("macros: [abc]", "machines[0].poll.macros[0]: expected a macro number or range"),
        ("macros: [{first: 1, last: 2, name: X}]", "machines[0].poll.macros[0].name: a single name fits one"),
        ("macros: [500, {first: 500, name_prefix: Macro}]",
         "machines[0].poll.macros[1]: metric name 'Macro/500' is already used by macros[0]"),
        ("params: [{number: 6711, name: Status/Run}]",
         "machines[0].poll.params[0].name: 'Status/Run': the folder 'Status' is reserved"),
        ("params: [{number: 1, name: 'a//b'}]", "machines[0].poll.params[0].name: 'a//b' is not a metric name"),
        ("periods: {status: 10ms}", "machines[0].poll.periods.status: Input should be greater than or equal"),
        ("periods: {status: fast}", "machines[0].poll.periods.status: expected a duration"),
        ("positions: [sideways]", "machines[0].poll.positions[0]: "),
        ("params: [{number: 1850, axis: some}]", "machines[0].poll.params[0]: axis must be 0..32 or 'all', got 'some'"),
    ],
)
def test_poll_plan_errors(poll: str, expected: str) -> None:
    problems = problems_of(_machine_with_poll(poll))
    assert any(p.startswith(expected) for p in problems), problems
