"""Metric aliases: unique across the whole edge node (all devices), stable across restarts.

A host maps alias -> metric from the births; keeping the same alias for the same (device, metric) across
daemon restarts means historians and tag providers never see a metric change identity. The map only grows.
"""

from __future__ import annotations

import logging

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
        self._dirty = False
        self._highest = 0  # the largest alias ever assigned or loaded (max() per new alias was O(n^2))
        if store is not None:
            self._load(store)

    def _load(self, store: StateStore) -> None:
        doc = store.load(DOCUMENT)
        if doc is None:
            return
        devices = doc.get("devices", {})
        if not isinstance(devices, dict):
            log.error("alias map ignored: 'devices' is not an object path=%s", store.path(DOCUMENT))
            return
        seen: set[int] = set()
        for device, names in devices.items():
            if not isinstance(names, dict):
                continue
            for name, alias in names.items():
                if isinstance(alias, int) and alias >= 0 and alias not in seen:
                    seen.add(alias)
                    self._devices.setdefault(device, {})[name] = alias
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
        self._reverse = None
        self._dirty = True
        return alias

    def resolve(self, alias: int) -> tuple[str, str] | None:
        """(device id, metric name) for an alias, or None if this node never assigned it."""
        if self._reverse is None:
            self._reverse = {a: (device, name) for device, names in self._devices.items()
                             for name, a in names.items()}
        return self._reverse.get(alias)

    def save(self) -> None:
        """Persist the map if it grew since the last save."""
        if not self._dirty or self._store is None:
            return
        try:
            self._store.save(DOCUMENT, {"version": 1, "devices": self._devices})
        except OSError as exc:  # a full disk: the map in memory stays right; the next save tries again
            log.warning("alias map not persisted, kept in memory error=%s", exc)
            return
        self._dirty = False
