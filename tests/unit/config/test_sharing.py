"""Machines configured alike share their equal config parts (one PollPlan for a fleet polling alike)."""

from __future__ import annotations

from edge.config import parse_config

HEAD = "mqtt: {host: 127.0.0.1, sparkplug: {group_id: g, edge_node_id: e}}\nmachines:\n"


def test_equal_poll_sections_are_one_object_and_different_ones_are_not() -> None:
    config = parse_config(HEAD + "  - {id: a, host: h1, poll: {macros: [500-509]}}\n"
                                 "  - {id: b, host: h2, poll: {macros: [500-509]}}\n"
                                 "  - {id: c, host: h3, poll: {macros: [500-501]}}\n", "t", {})
    a, b, c = config.machines
    assert a.poll is b.poll and a.timeouts is b.timeouts is c.timeouts
    assert c.poll is not a.poll and c.poll != a.poll
    assert (a.id, b.id, c.id, a.host, b.host) == ("a", "b", "c", "h1", "h2")


def test_a_shared_part_compares_as_before_so_reload_sees_the_same_changes() -> None:
    old = parse_config(HEAD + "  - {id: a, host: h1}\n  - {id: b, host: h2}\n", "t", {})
    new = parse_config(HEAD + "  - {id: a, host: h1}\n  - {id: b, host: h2, poll: {macros: [500-501]}}\n",
                       "t", {})
    assert old.machines[0] == new.machines[0]
    assert old.machines[1] != new.machines[1]
