"""Full disk (issue 16, points 6-8): state_dir on a 1 MB tmpfs. bdSeq, the spool's bound and drops, acks."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from edge.publish.bdseq import BdSeqCounter
from edge.publish.state_store import StateStore
from tests.small_disk import fill, small_disk


def test_bdseq_on_a_full_disk_is_used_anyway_warned_and_counted(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with small_disk(tmp_path / "state") as state:
        store = StateStore(state)
        counter = BdSeqCounter(store)
        assert counter.next_for_connect() == 0
        fill(state)
        with caplog.at_level(logging.WARNING, logger="edge.publish.bdseq"):
            assert counter.next_for_connect() == 1
            assert counter.next_for_connect() == 2
        assert counter.persist_failures == 2
        assert counter.current == 2
        assert "bdSeq not persisted" in caplog.text
        assert (store.load("sparkplug_bdseq") or {}).get("last") == 0  # the last value that fit
        assert not [p for p in state.iterdir() if p.name.startswith(".")], "a temp file was left behind"
