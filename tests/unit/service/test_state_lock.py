"""The state_dir lock: one holder, a refusal naming it, nothing created by a look, free again on release.
(Two real daemons and kill -9: tests/integration/test_one_instance.py.)"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from edge import ConfigError
from edge.service import state_lock
from edge.service.state_lock import LOCK_FILE, Holder, StateDirLock, held_message, holder


def test_a_second_lock_on_one_state_dir_is_refused_naming_the_holder(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(state_lock, "CONTENDED_RETRY_S", 0.0)
    state = tmp_path / "state"
    first = StateDirLock.acquire(state)  # makes state_dir
    try:
        assert (state / LOCK_FILE).read_text() == f"{os.getpid()}\n"
        found = holder(state)
        assert found is not None and found.pid == os.getpid()
        with pytest.raises(ConfigError) as refused:
            StateDirLock.acquire(state)  # another open file description: flock refuses it even in-process
        (line,) = refused.value.problems
        assert line.startswith(f"state_dir: {state} is in use by another focas-edge (PID {os.getpid()}")
    finally:
        first.release()
    assert holder(state) is None
    StateDirLock.acquire(state).release()


def test_looking_creates_nothing(tmp_path: Path) -> None:
    assert holder(tmp_path / "missing") is None
    assert holder(tmp_path) is None
    assert list(tmp_path.iterdir()) == []


def test_the_message_says_how_to_stop_the_holder(tmp_path: Path) -> None:
    service = held_message(tmp_path, Holder(42, "focas-edge.service"))
    assert "(PID 42, focas-edge.service;" in service and "(systemctl stop focas-edge)" in service
    assert "(kill 7)" in held_message(tmp_path, Holder(7, None))
    assert "a process whose PID is unknown" in held_message(tmp_path, Holder(None, None))
