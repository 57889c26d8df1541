"""Typed PMC ranges by element: `count:` elements from a first address, and errors that say what was meant."""

from __future__ import annotations

import textwrap

import pytest

from edge import ConfigError
from edge.config import PollPlan, parse_config


def pmc(*entries: str) -> list[str] | PollPlan:
    text = textwrap.dedent("""
        mqtt: {host: b, formats: [json]}
        machines:
          - id: m
            host: h
            poll:
              pmc:
        """) + "".join(f"        - {entry}\n" for entry in entries)
    try:
        return parse_config(text, "t.yaml", {}).machines[0].poll
    except ConfigError as exc:
        return exc.problems


def test_count_reads_that_many_elements_from_the_first_address() -> None:
    poll = pmc("{range: D100, count: 6, data_type: word}", "{area: D, start: 200, count: 2, data_type: long}",
               "{range: R10, count: 3}", "{range: R20, count: 2, data_type: bit}")
    assert isinstance(poll, PollPlan)
    words, longs, plain, bits = poll.pmc
    assert words.addresses() == [100, 102, 104, 106, 108, 110] and words.target.end == 111
    assert longs.addresses() == [200, 204] and longs.target.end == 207
    assert plain.addresses() == [10, 11, 12]
    assert len(bits.metric_names()) == 16 and bits.metric_names()[-1] == "PMC/R21.7"


@pytest.mark.parametrize(("entry", "message"), [
    ("{range: D100-D110, data_type: word}",
     "range: D100-D110 is 11 bytes, not a whole number of word (2-byte) elements. A range is byte addresses: "
     "for 6 words whose last starts at D110 write D100-D111 or {range: D100, count: 6}"),
    ("{area: D, start: 100, end: 104, data_type: long}",
     "end: D100-D104 is 5 bytes, not a whole number of long (4-byte) elements. A range is byte addresses: "
     "for 2 longs whose last starts at D104 write D100-D107 or {range: D100, count: 2}"),
    ("{range: D100-D102, data_type: long}",
     "range: D100-D102 is 3 bytes, not a whole number of long (4-byte) elements. A range is byte addresses: "
     "for 1 long write D100-D103 or {range: D100, count: 1}"),
    ("{range: D100-D103, count: 2, data_type: word}", "count: give count or an end address, not both"),
    ("{area: D, start: 100, end: 103, count: 2, data_type: word}", "count: give count or an end address, not both"),
    ("{range: D100, count: 0, data_type: word}", "count: Input should be greater than or equal to 1"),
])
def test_a_range_that_is_not_whole_elements_says_what_was_meant(entry: str, message: str) -> None:
    problems = pmc(entry)
    assert isinstance(problems, list)
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"machines[0].poll.pmc[0].{message}"), problems[0]
