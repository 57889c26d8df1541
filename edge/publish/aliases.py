"""Metric aliases: unique across the whole edge node (all devices), stable across restarts.

A host maps alias -> metric from the births; keeping the same alias for the same (device, metric) across
daemon restarts means historians and tag providers never see a metric change identity. The map only grows.

Persistence is a document plus a journal (edge.publish.alias_journal). Rewriting the whole document at every
new device cost O(metrics of the node) per birth: at 1,000 machines (~100,000 aliases, 2 MB of JSON) that
was ~0.8 s of the event loop per DBIRTH, and a fleet's first start never finished within its request
timeouts. A save now appends only the aliases new since the last one; the journal is folded into the
document when the map is loaded.

In memory a device's aliases are an array by position beside a name -> position index that every device
with the same metric names shares: a dict and an int object per metric were ~6 kB a machine of ~90 metrics.
"""

from __future__ import annotations

import logging
import weakref
from array import array
from collections.abc import Iterable

from edge.publish.alias_journal import AliasJournal
from edge.publish.state_store import StateStore

log = logging.getLogger(__name__)

NODE = ""  # the device id used for node-level metrics
DOCUMENT = "sparkplug_aliases"


class _Index(dict[str, int]):
    """Metric name -> position: shared by the devices whose names are the same, in the same order."""

    __slots__ = ("__weakref__", "names")

    def __init__(self, names: tuple[str, ...]) -> None:
        super().__init__((name, position) for position, name in enumerate(names))
        self.names = names


class _Known:
    """One device's aliases: by position in its (shared) index."""

    __slots__ = ("aliases", "index")

    def __init__(self, index: _Index, aliases: array[int]) -> None:
        self.index = index
        self.aliases = aliases

    def get(self, name: str) -> int | None:
        position = self.index.get(name)
        return None if position is None else self.aliases[position]

    def as_dict(self) -> dict[str, int]:
        return dict(zip(self.index.names, self.aliases, strict=True))


class AliasMap:
    """(device id, metric name) <-> alias, persisted in the state store when it grows.

    Stored per device (device -> name -> alias), as the file is: no tuple per metric. The reverse map
    (alias -> metric), needed only for commands sent by alias, is built on first use after a change.
    """

    def __init__(self, store: StateStore | None = None) -> None:
        self._store = store
        self._devices: dict[str, _Known] = {}
        self._indexes: weakref.WeakValueDictionary[tuple[str, ...], _Index] = weakref.WeakValueDictionary()
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
        loaded: dict[str, dict[str, int]] = {}
        for device, names in devices.items():
            if isinstance(names, dict):
                self._take(loaded.setdefault(device, {}), names, seen)
        assert self._journal is not None
        journaled = self._journal.read()
        for device, names in journaled:
            self._take(loaded.setdefault(device, {}), names, seen)
        for device, known in loaded.items():
            self._devices[device] = self._known(tuple(known), known.values())
        if journaled and self._write_document():  # folded into the document once per start
            self._journal.clear()

    def _take(self, known: dict[str, int], names: dict[str, object], seen: set[int]) -> None:
        for name, alias in names.items():
            if isinstance(alias, int) and alias >= 0 and alias not in seen and name not in known:
                seen.add(alias)
                known[name] = alias
                self._highest = max(self._highest, alias)

    def _known(self, names: tuple[str, ...], aliases: Iterable[int]) -> _Known:
        index = self._indexes.get(names)
        if index is None:
            index = self._indexes[names] = _Index(names)
        aliases = list(aliases)
        small = all(0 <= alias <= 0xFFFF_FFFF for alias in aliases)  # nearly always: 4 bytes each, not 8
        return _Known(index, array("I" if small else "q", aliases))

    def alias(self, device_id: str, name: str) -> int:
        """The alias of a metric, allocating the next free one (never reused) the first time."""
        known = self._devices.get(device_id)
        found = None if known is None else known.get(name)
        return found if found is not None else self.aliases(device_id, (name,))[0]

    def aliases(self, device_id: str, names: Iterable[str]) -> list[int]:
        """The aliases of a device's metrics, in order; the new names get the next free ones, in order."""
        names = list(names)
        known = self._devices.get(device_id)
        have: tuple[str, ...] = () if known is None else known.index.names
        new = [name for name in dict.fromkeys(names) if known is None or name not in known.index]
        if new:
            first = self._highest + 1
            self._highest += len(new)
            added = range(first, self._highest + 1)
            self._unsaved.setdefault(device_id, {}).update(zip(new, added, strict=True))
            known = self._devices[device_id] = self._known(
                (*have, *new), [*(known.aliases if known is not None else ()), *added])
            self._reverse = None
        assert known is not None
        index, aliases = known.index, known.aliases
        return [aliases[index[name]] for name in names]

    def resolve(self, alias: int) -> tuple[str, str] | None:
        """(device id, metric name) for an alias, or None if this node never assigned it."""
        if self._reverse is None:
            self._reverse = {a: (device, name) for device, known in self._devices.items()
                             for name, a in zip(known.index.names, known.aliases, strict=True)}
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
            devices = {device: known.as_dict() for device, known in self._devices.items()}
            self._store.save(DOCUMENT, {"version": 1, "devices": devices})
        except OSError as exc:  # the journal stays and is folded in at the next start
            log.warning("alias map document not rewritten, journal kept error=%s", exc)
            return False
        return True
