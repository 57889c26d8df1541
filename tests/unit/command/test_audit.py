"""The write audit file: bounded by size out of the box, rotated by the daemon, and no line lost unseen."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import pytest

from edge.command.audit import AUDIT_FILE, AuditLog, AuditRecord
from edge.config import parse_config
from edge.service.settings import command_settings


def record(n: int, value: object = 1.0) -> AuditRecord:
    return AuditRecord(time="2026-01-01T00:00:00.000Z", machine="m1", source="json", topic="focas/m1/cmd",
                       client_id=None, request_id=n, target="macro:500", value=value, old=None, new=None,
                       outcome="ok")


def lines(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_the_file_rotates_past_max_bytes_and_keeps_only_keep_old_files(tmp_path: Path) -> None:
    audit = AuditLog(tmp_path, max_bytes=2000, keep=2)
    for n in range(200):
        audit.write(record(n))
    audit.close()
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == [AUDIT_FILE, f"{AUDIT_FILE}.1", f"{AUDIT_FILE}.2"]
    assert all((tmp_path / name).stat().st_size <= 2000 for name in files)
    # Newest in the live file, the rotated ones older and contiguous: nothing lost inside the window kept.
    kept = lines(tmp_path / f"{AUDIT_FILE}.2") + lines(tmp_path / f"{AUDIT_FILE}.1") + lines(tmp_path / AUDIT_FILE)
    ids = [line["request_id"] for line in kept]
    assert ids == list(range(ids[0], 200))


def test_the_default_bound_is_10_mb_times_5_and_configurable() -> None:
    base = "mqtt: {host: 127.0.0.1, formats: [json]}\nmachines: [{id: m1, host: 127.0.0.1}]\nstate_dir: /tmp/x\n"
    default = command_settings(parse_config(base))
    assert (default.audit_max_bytes, default.audit_keep) == (10 * 1024 * 1024, 5)
    chosen = command_settings(parse_config(base + "writes: {audit: {max_bytes: 2MB, keep: 3}}\n"))
    assert (chosen.audit_max_bytes, chosen.audit_keep) == (2_000_000, 3)


def test_an_unwritable_file_is_an_error_once_the_lines_go_to_the_log_and_it_recovers(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    blocked = tmp_path / "state"
    blocked.write_text("a file where the state directory should be")
    audit = AuditLog(blocked)
    with caplog.at_level(logging.INFO, logger="edge.command.audit"):
        audit.write(record(1))
        audit.write(record(2))
    errors = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 1 and str(blocked / AUDIT_FILE) in errors[0].getMessage()
    assert audit.unwritten == 2
    assert sum('"request_id":1' in r.getMessage() for r in caplog.records) == 1  # the line itself is in the log
    blocked.unlink()
    blocked.mkdir()
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="edge.command.audit"):
        audit.write(record(3))
    assert [line["request_id"] for line in lines(blocked / AUDIT_FILE)] == [3]
    assert any("writable again" in r.getMessage() and "lines_only_in_log=2" in r.getMessage()
               for r in caplog.records)


def test_non_finite_values_stay_strict_json(tmp_path: Path) -> None:
    audit = AuditLog(tmp_path)
    audit.write(record(1, value=[math.nan, math.inf, 1.5]))
    audit.close()
    text = (tmp_path / AUDIT_FILE).read_text()
    (line,) = [json.loads(t, parse_constant=lambda c: pytest.fail(f"{c} is not JSON")) for t in text.splitlines()]
    assert line["value"] == ["nan", "inf", 1.5]
