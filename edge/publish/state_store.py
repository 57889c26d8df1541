"""Small JSON documents in state_dir that must survive a restart (bdSeq, the alias map).

Every write goes to a temporary file in the same directory, is fsynced, then renamed over the old one,
so a crash or power loss leaves either the old or the new document, never a torn one.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from edge.statefile import write_atomically

log = logging.getLogger(__name__)


class StateStore:
    """Named JSON documents under one directory, written atomically."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)

    def path(self, name: str) -> Path:
        return self.directory / f"{name}.json"

    def load(self, name: str) -> dict[str, Any] | None:
        """The stored document, or None if there is none; a corrupt file is logged and treated as absent."""
        path = self.path(name)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        try:
            doc = json.loads(text)
        except ValueError as exc:
            log.error("state file unreadable, starting fresh path=%s error=%s", path, exc)
            return None
        if not isinstance(doc, dict):
            log.error("state file is not a JSON object, starting fresh path=%s", path)
            return None
        return doc

    def save(self, name: str, doc: dict[str, Any]) -> None:
        """Replace the document atomically (temp file, fsync, rename, fsync the directory)."""
        self.directory.mkdir(parents=True, exist_ok=True)
        data = json.dumps(doc, separators=(",", ":"), sort_keys=True).encode("utf-8")
        write_atomically(self.path(name), data)
