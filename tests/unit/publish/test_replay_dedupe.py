"""DeliveredValues: a replayed sample is skipped only when a barrier taken after its copy proves the copy."""

from __future__ import annotations

import json

from hypothesis import given
from hypothesis import strategies as st

from edge.publish.replay_dedupe import DeliveredValues, value_key
from edge.samples import MetricType, Sample


def s(ts: int, value: object = 1.5, name: str = "Macro/500") -> Sample:
    return Sample(name, value, MetricType.DOUBLE, ts)


def test_sent_on_this_connection_is_skipped_and_counted() -> None:
    d = DeliveredValues()
    d.record("m1", [s(1), s(2)])
    assert d.fresh("m1", [s(1), s(2), s(3)]) == [s(3)]
    assert d.fresh("m2", [s(1)]) == [s(1)], "another device's value is not the same value"
    assert d.fresh("m1", [s(1, value=2.5)]) == [s(1, value=2.5)], "same timestamp, other value: not a repeat"
    assert d.skipped == 2


def test_a_new_connection_forgets_what_was_not_proven() -> None:
    d = DeliveredValues()
    d.record("m1", [s(1)])
    mark = d.mark()
    d.record("m1", [s(2)])  # sent after the barrier went out: that barrier proves nothing about it
    d.proven(mark)
    d.connection_lost()
    assert d.fresh("m1", [s(1), s(2)]) == [s(2)]


def test_forget_when_the_spool_is_empty_and_the_limit_holds() -> None:
    d = DeliveredValues(limit=3)
    d.record("m1", [s(1), s(2), s(3)])
    d.record("m1", [s(4)])
    assert len(d) == 3
    d.forget()
    assert len(d) == 0 and d.fresh("m1", [s(1)]) == [s(1)]


def test_values_compare_as_the_spool_stores_them() -> None:
    d = DeliveredValues()
    d.record("m1", [Sample("Alarm/Event", {"b": 1, "a": [2]}, MetricType.STRING, 5)])
    assert d.fresh("m1", [Sample("Alarm/Event", {"a": [2], "b": 1}, MetricType.STRING, 5)]) == []


def test_an_acknowledged_rows_samples_are_forgotten() -> None:
    d = DeliveredValues()
    d.record("m1", [s(1), s(2)])
    d.proven(d.mark())
    d.discard("m1", [s(1)])
    assert len(d) == 1 and d.fresh("m1", [s(1), s(2)]) == [s(1)]


@given(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(),
                 st.lists(st.one_of(st.integers(), st.floats(allow_nan=False), st.text()), max_size=4)))
def test_a_value_key_is_the_value_as_the_spool_writes_it(value: object) -> None:
    """The fast spellings of scalars equal json's, so a value and its copy through the spool share a key."""
    assert value_key(value) == json.dumps(value, separators=(",", ":"), sort_keys=True, default=str)


def test_a_replayed_row_is_skipped_whole_until_acknowledged() -> None:
    d = DeliveredValues()
    d.record_row(7)
    assert d.has_row(7) and not d.has_row(8)
    d.connection_lost()
    assert not d.has_row(7), "sent on a connection that was lost: it may not have arrived"
    d.record_row(7)
    d.proven(d.mark())
    d.connection_lost()
    assert d.has_row(7), "proven by a barrier: skipped on the next connection too"
    d.forget_rows([7])
    assert not d.has_row(7) and len(d) == 0


def test_timestamps_never_recorded_pass_without_a_key_and_the_index_follows_the_record() -> None:
    d = DeliveredValues()
    d.record("m1", [s(1)])
    tick = [s(2), s(3)]
    assert d.fresh("m1", tick) is tick, "no timestamp in common: the samples themselves, no key built"
    assert d.fresh("m1", [s(1), s(2)]) == [s(2)]
    d.connection_lost()
    assert d.fresh("m1", [s(1)]) == [s(1)], "the unproven record is gone, with its timestamps"
    d.record("m1", [s(4)])
    d.proven(d.mark())
    d.connection_lost()
    assert d.fresh("m1", [s(4), s(5)]) == [s(5)], "proven values stay indexed across connections"
    d.forget()
    assert d.fresh("m1", [s(4)]) == [s(4)] and d.skipped == 2


def test_birth_values_are_kept_by_reference_and_follow_the_connection() -> None:
    d = DeliveredValues()
    d.record_birth("m1", [s(1), s(2, name="Macro/501")])
    assert d.fresh("m1", [s(1), s(1, value=2.5), s(3)]) == [s(1, value=2.5), s(3)]
    assert d.fresh("m1", [s(2)]) == [s(2)], "the birth carried Macro/501 at 2, not Macro/500"
    d.connection_lost()
    assert d.fresh("m1", [s(1)]) == [s(1)], "a birth not proven may not have arrived"
    d.record_birth("m1", [s(1)])
    d.proven(d.mark())
    d.record_birth("m1", [s(4)])  # a rebirth after the barrier: not proven by it
    d.connection_lost()
    assert d.fresh("m1", [s(1), s(4)]) == [s(4)] and len(d) == 0, "births are not keys"
    d.forget()
    assert d.fresh("m1", [s(1)]) == [s(1)]


def test_a_birth_recorded_by_a_layouts_slots_skips_what_it_carried() -> None:
    """The session records a DBIRTH as its device table's samples by position and the layout's shared
    slots (no dict per device): the same answers as a birth recorded as samples."""
    d = DeliveredValues()
    slots = {"Macro/500": (0,), "Macro/501": (1,), "Macro/502": (2,)}
    d.record_birth_slots("m1", slots, (s(1), s(2, name="Macro/501"), None))
    assert d.fresh("m1", [s(1), s(1, value=2.5), s(3), s(2, name="Macro/502")]) == \
        [s(1, value=2.5), s(3), s(2, name="Macro/502")]
    assert d.fresh("m1", [s(2)]) == [s(2)], "the birth carried Macro/501 at 2, not Macro/500"
    d.proven(d.mark())
    d.connection_lost()
    assert d.fresh("m1", [s(1), s(4)]) == [s(4)], "a proven birth stays indexed across connections"


def test_fresh_rows_leaves_out_what_births_carried_and_defers_to_samples_where_keys_may_match() -> None:
    d = DeliveredValues()
    d.record_birth("m1", [s(1), s(2, name="Macro/501")])
    rows = [["Macro/500", 1.5, "Double", 1, 192], ["Macro/500", 2.5, "Double", 1, 192],
            ["Macro/501", 1.5, "Double", 3, 192]]
    assert d.fresh_rows("m1", rows) == rows[1:] and d.skipped == 1
    assert d.fresh_rows("m1", [["Macro/500", 1.5, "Double", 1.0, 192]]) is None, "a timestamp not as written"
    d.record("m1", [s(3)])
    assert d.fresh_rows("m1", rows) is None, "a key at 3 may match: decided on samples"
    assert d.fresh_rows("m1", rows[:2]) == rows[1:2]
    d.connection_lost()
    assert d.fresh_rows("m1", rows) == rows, "nothing proven: every value goes again"
