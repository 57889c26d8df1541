"""The alias map's persistence: a document plus a journal of what each save added (edge.publish.aliases)."""

from __future__ import annotations

import json
from pathlib import Path

from edge.publish.aliases import DOCUMENT, AliasMap
from edge.publish.state_store import StateStore


def names(count: int) -> list[str]:
    return [f"Macro/{500 + i}" for i in range(count)]


def test_a_save_appends_only_what_is_new_and_a_restart_folds_it_into_the_document(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    aliases = AliasMap(store)
    first = {n: aliases.alias("m1", n) for n in names(50)}
    aliases.save()
    journal = store.path(DOCUMENT).with_suffix(".journal")
    size = journal.stat().st_size
    second = {n: aliases.alias("m2", n) for n in names(2)}
    aliases.save()
    added = journal.read_text().splitlines()[-1]
    assert json.loads(added) == ["m2", second]
    assert journal.stat().st_size - size == len(added) + 1, "the second save wrote m2's two aliases, not the map"
    aliases.save()  # nothing new: nothing written
    assert journal.stat().st_size - size == len(added) + 1

    again = AliasMap(StateStore(tmp_path))
    assert [again.alias("m1", n) for n in names(50)] == list(first.values())
    assert again.alias("m2", names(1)[0]) == second[names(1)[0]]
    assert again.alias("m3", "x") == max(second.values()) + 1, "never reused after a restart"
    assert not journal.exists(), "folded into the document at load"
    assert json.loads(store.path(DOCUMENT).read_text())["devices"]["m1"] == first


def test_a_torn_last_journal_line_is_skipped_and_the_rest_kept(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    aliases = AliasMap(store)
    kept = aliases.alias("m1", "x")
    aliases.save()
    journal = store.path(DOCUMENT).with_suffix(".journal")
    with journal.open("a") as handle:
        handle.write('["m2",{"y":')  # what a power loss can leave
    again = AliasMap(StateStore(tmp_path))
    assert again.resolve(kept) == ("m1", "x")
    assert again.alias("m2", "y") == kept + 1


def test_the_document_written_before_the_journal_existed_still_loads(tmp_path: Path) -> None:
    store = StateStore(tmp_path)
    store.save(DOCUMENT, {"version": 1, "devices": {"m1": {"a": 3, "b": 7}}})
    aliases = AliasMap(store)
    assert (aliases.alias("m1", "b"), aliases.alias("m1", "c")) == (7, 8)


def test_a_journal_entry_already_in_the_document_is_not_taken_twice(tmp_path: Path) -> None:
    """A crash between writing the folded document and removing the journal leaves both."""
    store = StateStore(tmp_path)
    store.save(DOCUMENT, {"version": 1, "devices": {"m1": {"a": 1}}})
    store.path(DOCUMENT).with_suffix(".journal").write_text('["m1",{"a":1}]\n["m1",{"b":2}]\n')
    aliases = AliasMap(store)
    assert (aliases.resolve(1), aliases.resolve(2)) == (("m1", "a"), ("m1", "b"))
    assert aliases.alias("m2", "c") == 3


def test_bulk_aliases_assign_new_names_in_order_and_devices_alike_share_their_index() -> None:
    aliases = AliasMap()
    assert aliases.aliases("m1", ["a", "b", "a"]) == [1, 2, 1]
    assert aliases.aliases("m2", ["a", "b"]) == [3, 4]
    assert aliases.aliases("m1", ["c", "b"]) == [5, 2]
    assert aliases.alias("m2", "a") == 3 and aliases.resolve(5) == ("m1", "c")
    assert aliases._devices["m2"].index is aliases._known(("a", "b"), [9, 9]).index
