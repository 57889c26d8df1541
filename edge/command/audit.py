"""The write audit trail: one JSON line per attempt, accepted or refused, to a file and a logger.

The file is `<state_dir>/write-audit.jsonl`, appended and flushed line by line (rotate it with logrotate
`copytruncate`). The same line goes to the `edge.command.audit` logger (INFO for success, WARNING
otherwise), so journald has it too.
"""

from __future__ import annotations

import json
import logging
import threading
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO

log = logging.getLogger("edge.command.audit")

AUDIT_FILE = "write-audit.jsonl"


@dataclass(frozen=True, slots=True)
class AuditRecord:
    """One write attempt. `outcome` is "ok" or an edge.command.errors code."""

    time: str
    machine: str
    source: str  # "json" or "sparkplug"
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
    """Appends AuditRecords; a file that cannot be written is logged once and then only the logger is used."""

    def __init__(self, state_dir: Path) -> None:
        self.path = state_dir / AUDIT_FILE
        self._file: IO[str] | None = None
        self._failed = False
        self._lock = threading.Lock()

    def write(self, record: AuditRecord) -> None:
        line = json.dumps(asdict(record), separators=(",", ":"), default=_jsonable)
        log.log(logging.INFO if record.outcome == "ok" else logging.WARNING, "write %s", line)
        with self._lock:
            handle = self._open()
            if handle is None:
                return
            try:
                handle.write(line + "\n")
                handle.flush()
            except OSError as exc:
                self._give_up(exc)

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def _open(self) -> IO[str] | None:
        if self._file is None and not self._failed:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._file = self.path.open("a", encoding="utf-8")
            except OSError as exc:
                self._give_up(exc)
        return self._file

    def _give_up(self, exc: OSError) -> None:
        self._failed = True
        self._file = None
        log.error("write audit file unusable, logging only path=%s error=%s", self.path, exc)


def _jsonable(value: object) -> object:
    if isinstance(value, bytes):
        return value.hex()
    return str(value)
