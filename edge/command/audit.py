"""The write audit trail: one JSON line per attempt, accepted or refused, to a file and a logger.

The file is `<state_dir>/write-audit.jsonl`, appended and flushed line by line. The daemon bounds it itself
(rather than shipping a logrotate rule): it works the same for a venv, a .deb or a container install, and
renaming inside the writer never loses the line that `copytruncate` can lose between its copy and its
truncate. When the next line would take the file past `max_bytes`, it becomes `.1` (`.1` becomes `.2`, ...,
the oldest beyond `keep` is deleted): at most max_bytes x (keep + 1) on disk.

The same line always goes to the `edge.command.audit` logger first (INFO for success, WARNING otherwise), so
journald has it even when the file cannot be written; such lines are counted (`unwritten`), the failure is
logged once as an ERROR, and the file is tried again at the next line.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import threading
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO

log = logging.getLogger("edge.command.audit")

AUDIT_FILE = "write-audit.jsonl"
DEFAULT_MAX_BYTES = 10 * 1024 * 1024
DEFAULT_KEEP = 5


@dataclass(frozen=True, slots=True)
class AuditRecord:
    """One write attempt. `outcome` is "ok" or an edge.command.errors code."""

    time: str
    machine: str
    source: str  # "json", "sparkplug" or "opcua"
    topic: str
    client_id: str | None
    request_id: object
    target: str | None
    value: object
    old: object
    new: object
    outcome: str
    message: str | None = None


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


class AuditLog:
    """Appends AuditRecords to a size-bounded file set; a failing file costs the file line, never the log line."""

    def __init__(self, state_dir: Path, max_bytes: int = DEFAULT_MAX_BYTES, keep: int = DEFAULT_KEEP) -> None:
        self.path = state_dir / AUDIT_FILE
        self.max_bytes = max_bytes
        self.keep = keep
        self.unwritten = 0  # lines that reached the logger but not the file
        self._file: IO[str] | None = None
        self._failing = False
        self._lock = threading.Lock()

    def write(self, record: AuditRecord) -> None:
        line = encode(record)
        log.log(logging.INFO if record.outcome == "ok" else logging.WARNING, "write %s", line)
        with self._lock:
            try:
                handle = self._handle(len(line.encode("utf-8")) + 1)
                handle.write(line + "\n")
                handle.flush()
            except OSError as exc:
                self._failed(exc)
            else:
                self._recovered()

    def close(self) -> None:
        with self._lock:
            self._close()

    def _handle(self, incoming: int) -> IO[str]:
        """The open file, rotated first if `incoming` more bytes would pass max_bytes."""
        if self._file is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self.path.open("a", encoding="utf-8")
        size = os.fstat(self._file.fileno()).st_size
        if size > 0 and size + incoming > self.max_bytes:
            self._close()
            self._rotate()
            self._file = self.path.open("a", encoding="utf-8")
        return self._file

    def _rotate(self) -> None:
        """write-audit.jsonl -> .1 -> .2 ... -> .keep; the oldest is replaced."""
        for index in range(self.keep - 1, 0, -1):
            older = self._numbered(index)
            if older.exists():
                older.replace(self._numbered(index + 1))
        self.path.replace(self._numbered(1))

    def _numbered(self, index: int) -> Path:
        return self.path.with_name(f"{self.path.name}.{index}")

    def _failed(self, exc: OSError) -> None:
        self.unwritten += 1
        self._close()
        if not self._failing:
            self._failing = True
            log.error("write audit file unwritable; audit lines go to the log only until it is writable again "
                      "path=%s error=%s", self.path, exc)

    def _recovered(self) -> None:
        if self._failing:
            self._failing = False
            log.warning("write audit file writable again path=%s lines_only_in_log=%d", self.path, self.unwritten)

    def _close(self) -> None:
        if self._file is not None:
            with contextlib.suppress(OSError):  # its flush failing: the line is already counted unwritten
                self._file.close()
            self._file = None


def encode(record: AuditRecord) -> str:
    """One strict-JSON line: NaN/Infinity (a refused value) as strings, bytes as hex, anything else as str."""
    return json.dumps(_strict(asdict(record)), separators=(",", ":"), default=_jsonable, allow_nan=False)


def _strict(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {key: _strict(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(item) for item in value]
    return value


def _jsonable(value: object) -> object:
    if isinstance(value, bytes):
        return value.hex()
    return str(value)
