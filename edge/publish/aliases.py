"""Metric aliases: unique across the whole edge node (all devices), stable across restarts.

A host maps alias -> metric from the births; keeping the same alias for the same (device, metric) across
daemon restarts means historians and tag providers never see a metric change identity. The map only grows.

Persistence is a document plus a journal (edge.publish.alias_journal). Rewriting the whole document at every
new device cost O(metrics of the node) per birth: at 1,000 machines (~100,000 aliases, 2 MB of JSON) that
was ~0.8 s of the event loop per DBIRTH, and a fleet's first start never finished within its request
timeouts. A save now appends only the aliases new since the last one; the journal is folded into the
document when the map is loaded.
"""

from __future__ import annotations

import logging

from edge.publish.alias_journal import AliasJournal
from edge.publish.state_store import StateStore

log = logging.getLogger(__name__)

NODE = ""  # the device id used for node-level metrics
DOCUMENT = "sparkplug_aliases"


class AliasMap:
    """(device id, metric name) <-> alias, persisted in the state store when it grows.

    Stored per device (device -> name -> alias), as the file is: no tuple per metric. The reverse map
    (alias -> metric), needed only for commands sent by alias, is built on first use after a change.
    """

    def __init__(self, store: StateStore | None = None) -> None:
        self._store = store
        self._devices: dict[str, dict[str, int]] = {}
        self._reverse: dict[int, tuple[str, str]] | None = None
        self._unsaved: dict[str, dict[str, int]] = {}  # assigned since the last save, per device
        self._highest = 0  # the largest alias ever assigned or loaded (max() per new alias was O(n^2))
        self._journal = AliasJournal(store.path(DOCUMENT).with_suffix(".journal")) if store is not None else None
        if store is not None:
            self._load(store)

    def _load(self, store: StateStore) -> None:
        doc = store.load(DOCUMENT)
        devices = doc.get("devices", {}) if doc is not None else {}
        if not isinstance(devices, dict):
            log.error("alias map ignored: 'devices' is not an object path=%s", store.path(DOCUMENT))
            devices = {}
        seen: set[int] = set()
        for device, names in devices.items():
            if isinstance(names, dict):
                self._take(device, names, seen)
        assert self._journal is not None
        journaled = self._journal.read()
        for device, names in journaled:
            self._take(device, names, seen)
        if journaled and self._write_document():  # folded into the document once per start
            self._journal.clear()

    def _take(self, device: str, names: dict[str, object], seen: set[int]) -> None:
        known = self._devices.setdefault(device, {})
        for name, alias in names.items():
            if isinstance(alias, int) and alias >= 0 and alias not in seen and name not in known:
                seen.add(alias)
                known[name] = alias
                self._highest = max(self._highest, alias)

    def alias(self, device_id: str, name: str) -> int:
        """The alias of a metric, allocating the next free one (never reused) the first time."""
        names = self._devices.get(device_id)
        if names is None:
            names = self._devices[device_id] = {}
        found = names.get(name)
        if found is not None:
            return found
        self._highest = alias = self._highest + 1
        names[name] = alias
        self._unsaved.setdefault(device_id, {})[name] = alias
        self._reverse = None
        return alias

    def resolve(self, alias: int) -> tuple[str, str] | None:
        """(device id, metric name) for an alias, or None if this node never assigned it."""
        if self._reverse is None:
            self._reverse = {a: (device, name) for device, names in self._devices.items()
                             for name, a in names.items()}
        return self._reverse.get(alias)

    def save(self) -> None:
        """Persist the aliases assigned since the last save (one journal line each device)."""
        if not self._unsaved or self._journal is None:
            return
        try:
            self._journal.append(self._unsaved)
        except OSError as exc:  # a full disk: the map in memory stays right; the next save tries again
            log.warning("alias map not persisted, kept in memory error=%s", exc)
            return
        self._unsaved = {}

    def _write_document(self) -> bool:
        assert self._store is not None
        try:
            self._store.save(DOCUMENT, {"version": 1, "devices": self._devices})
        except OSError as exc:  # the journal stays and is folded in at the next start
            log.warning("alias map document not rewritten, journal kept error=%s", exc)
            return False
        return True
