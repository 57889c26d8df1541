"""`--log-format json`: one parseable object per line for log shippers; text stays the default."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge.cli import build_parser, main


@pytest.fixture(autouse=True)
def _restore_root_logger() -> Iterator[None]:
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def _run_and_log(tmp_path: Path, *flags: str) -> None:
    missing = tmp_path / "missing.yaml"
    main([*flags, "check-config", "-q", str(missing)])
    try:
        raise RuntimeError("boom")
    except RuntimeError:
        logging.getLogger("edge.test").exception("machine %s lost", "mill-1")


def test_json_format_writes_one_object_per_line_with_stable_keys(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    _run_and_log(tmp_path, "--log-format", "json")
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("{")]
    assert len(lines) == 1
    entry = json.loads(lines[0])
    assert entry["level"] == "ERROR"
    assert entry["logger"] == "edge.test"
    assert entry["message"] == "machine mill-1 lost"
    assert "RuntimeError: boom" in entry["exc"]
    assert entry["ts"].endswith("+00:00")


def test_text_stays_the_default(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _run_and_log(tmp_path)
    err = capsys.readouterr().err
    assert "ERROR edge.test: machine mill-1 lost" in err
    assert not any(line.startswith("{") for line in err.splitlines())


def test_an_unknown_log_format_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["--log-format", "xml", "check-config", "x"])
    assert exc.value.code == 2
    assert "--log-format" in capsys.readouterr().err
