"""What a host already has, so the spool's replay does not send it twice (same device, metric, CNC
timestamp and value: a historian would store it twice).

Where repeats come from: samples held while the node cannot publish live (a rebirth pending, the primary
host offline) are spooled, and the births that follow carry each metric's latest value -- the newest held
ones -- and the events a rebirth held; live batches still unconfirmed when a hold begins are spooled behind
them although they went out; and rows a replay sent before its session ended (a host going offline) come
back in the next one. The publisher records all of these as *sent* on the current connection; a delivery
barrier on that connection (a probe's PUBACK, or the NDEATH's) makes them *proven*. The replay skips a
sample found in either set:
- proven: it arrived (the barrier's PUBACK covers everything sent before it on that connection);
- sent on the current connection: the row is only acknowledged after a barrier on this same connection,
  which will prove the earlier copy too. A new connection forgets what was sent but not proven.
Replayed rows are recorded by their spool row id, not value by value (a 1,000-machine backlog is 12,000
rows a second to replay: three keys a value cost ~40 % of a row's replay), and a row proven or sent on this
connection is skipped whole. A replayed row is forgotten once it is acknowledged (it cannot come back), so
the record stays the size of the births, the unconfirmed live batches and one replay batch; everything is
forgotten when the spool has nothing left to replay. Per device, the CNC timestamps of the recorded values
are indexed (a superset: rebuilt when the record shrinks by a connection or the spool's end), so a spooled
tick whose timestamps the host never got is passed without building a key.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from operator import attrgetter
from typing import Any

from edge.samples import Sample

Key = tuple[str, str, int, str]
DEFAULT_LIMIT = 200_000  # keys kept per connection (~30 MB at worst); beyond it nothing more is recorded
# Built once: json.dumps with options builds a new encoder per call, twice the cost of a replayed sample's key.
_VALUE_ENCODER = json.JSONEncoder(separators=(",", ":"), sort_keys=True, default=str)


_encode_text = _VALUE_ENCODER.encode  # a str goes straight to the C string encoder
_INFINITIES = (float("inf"), float("-inf"))


def value_key(value: object) -> str:
    """The value as the spool stores it (JSON), so a copy that went through the spool compares equal.

    The scalars nearly every metric carries are spelled here as json writes them (a float's repr, an int's
    digits): the encoder's general path costs ~5 us a value, three keys a replayed sample."""
    kind = type(value)
    if kind is float:
        if value == value and value not in _INFINITIES:  # json spells NaN and the infinities its own way
            return float.__repr__(value)
    elif kind is int:
        return int.__repr__(value)
    elif kind is str:
        return _encode_text(value)
    elif kind is bool:
        return "true" if value else "false"
    elif value is None:
        return "null"
    return _VALUE_ENCODER.encode(value)


_timestamp_of = attrgetter("timestamp_ms")


def _carried(births: Sequence[_SlotBirth], name: str, timestamp_ms: int, value: object) -> bool:
    """One of these births carried this very value (name, CNC timestamp, value as the spool spells it)."""
    for b in births:
        carried = b.get(name)
        if carried is not None and carried.timestamp_ms == timestamp_ms \
                and value_key(carried.value) == value_key(value):
            return True
    return False


class _SlotBirth:
    """A birth's values by position in a shared layout; reads like a dict by metric name (get, values)."""

    __slots__ = ("last", "slots")

    def __init__(self, slots: Mapping[str, tuple[Any, ...]], last: Sequence[Sample | None]) -> None:
        self.slots = slots
        self.last = last

    def get(self, name: str) -> Sample | None:
        slot = self.slots.get(name)
        return None if slot is None else self.last[slot[0]]

    def values(self) -> list[Sample]:
        return [s for s in self.last if s is not None]



def _key(device_id: str, sample: Sample) -> Key:
    return device_id, sample.name, sample.timestamp_ms, value_key(sample.value)


class DeliveredValues:
    """(device, metric, CNC timestamp, value) of what the host has (proven) or was sent on this connection,
    and the spool rows a replay sent (proven, or sent on this connection)."""

    def __init__(self, limit: int = DEFAULT_LIMIT) -> None:
        self._proven: set[Key] = set()
        self._sent: dict[Key, int] = {}  # key -> the record call that added it (a barrier proves earlier ones)
        # The values births carried, per device: the samples themselves by metric name, no key built (a
        # DBIRTH of every machine is every metric of the fleet: ~20 MB of keys at 1,000 x 100 metrics).
        self._births_proven: dict[str, list[_SlotBirth]] = {}
        self._births_sent: dict[str, list[tuple[int, _SlotBirth]]] = {}
        self._stamps: dict[str, set[int]] = {}  # device -> timestamps of its keys and births (and maybe gone ones)
        self._key_stamps: dict[str, set[int]] = {}  # device -> timestamps of its keys alone (a superset too)
        self._rows_proven: set[int] = set()
        self._rows_sent: dict[int, int] = {}  # spool row id -> the record call that sent it
        self._calls = 0
        self._limit = limit
        self.skipped = 0  # replayed samples left out as duplicates, since the process started

    def __len__(self) -> int:
        return len(self._proven) + len(self._sent) + len(self._rows_proven) + len(self._rows_sent)

    def record(self, device_id: str, samples: Iterable[Sample]) -> None:
        """These samples went out on the current connection (call after publishing them)."""
        if len(self) >= self._limit:
            return
        self._calls += 1
        call = self._calls
        stamps = self._stamps.setdefault(device_id, set())
        key_stamps = self._key_stamps.setdefault(device_id, set())
        for s in samples:
            self._sent.setdefault(_key(device_id, s), call)
            stamps.add(s.timestamp_ms)
            key_stamps.add(s.timestamp_ms)

    def record_birth(self, device_id: str, values: Iterable[Sample]) -> None:
        """A DBIRTH carrying these values (one per metric) went out on the current connection."""
        last = list(values)
        self.record_birth_slots(device_id, {s.name: (i,) for i, s in enumerate(last)}, last)

    def record_birth_slots(self, device_id: str, slots: Mapping[str, tuple[Any, ...]],
                           last: Sequence[Sample | None]) -> None:
        """record_birth for a DBIRTH of `last`, a device table's samples by position (`slots`: name ->
        (position, ...), shared by the devices declared alike): no dict of its own per device (~5 kB at 100
        metrics, 1,000 of them kept until the replay ends)."""
        self._add_birth(device_id, _SlotBirth(slots, last))

    def _add_birth(self, device_id: str, birth: _SlotBirth) -> None:
        self._calls += 1
        self._births_sent.setdefault(device_id, []).append((self._calls, birth))
        self._stamps.setdefault(device_id, set()).update(map(_timestamp_of, birth.values()))

    def record_row(self, row_id: int) -> None:
        """This spool row was replayed whole on the current connection."""
        if len(self) >= self._limit:
            return
        self._calls += 1
        self._rows_sent[row_id] = self._calls

    def has_row(self, row_id: int) -> bool:
        """The row was replayed on this connection, or proven earlier: do not send it again."""
        return row_id in self._rows_proven or row_id in self._rows_sent

    def mark(self) -> int:
        """Taken just before a barrier is published: it proves what was recorded up to here."""
        return self._calls

    def proven(self, mark: int) -> None:
        """The barrier published at `mark` on the current connection was acknowledged."""
        done = [key for key, call in self._sent.items() if call <= mark]
        self._proven.update(done)
        for key in done:
            del self._sent[key]
        rows = [row for row, call in self._rows_sent.items() if call <= mark]
        self._rows_proven.update(rows)
        for row in rows:
            del self._rows_sent[row]
        for device_id, births in list(self._births_sent.items()):
            self._births_proven.setdefault(device_id, []).extend(b for call, b in births if call <= mark)
            later = [(call, b) for call, b in births if call > mark]
            if later:
                self._births_sent[device_id] = later
            else:
                del self._births_sent[device_id]

    def forget_rows(self, row_ids: Iterable[int]) -> None:
        """These rows left the spool (acknowledged): no replay can repeat them."""
        for row_id in row_ids:
            self._rows_proven.discard(row_id)
            self._rows_sent.pop(row_id, None)

    def discard(self, device_id: str, samples: Iterable[Sample]) -> None:
        """These samples' rows left the spool (acknowledged): no replay can repeat them, keep no memory of
        their keys (births are kept until the spool is empty)."""
        if not self._proven and not self._sent:
            return
        stamps = self._stamps.get(device_id)
        if not stamps:
            return
        for s in samples:
            if s.timestamp_ms in stamps:
                key = _key(device_id, s)
                self._sent.pop(key, None)
                self._proven.discard(key)

    def connection_lost(self) -> None:
        """What the old connection sent without proof may not have arrived."""
        self._sent = {}
        self._births_sent = {}
        self._rows_sent = {}
        self._reindex()

    def forget(self) -> None:
        """The spool is empty: no replayed row can repeat any of it."""
        self._proven = set()
        self._sent = {}
        self._births_proven = {}
        self._births_sent = {}
        self._stamps = {}
        self._key_stamps = {}
        self._rows_proven = set()
        self._rows_sent = {}

    def _reindex(self) -> None:
        stamps: dict[str, set[int]] = {}
        for device_id, _, ts, _ in self._proven:
            stamps.setdefault(device_id, set()).add(ts)
        self._key_stamps = {device_id: set(found) for device_id, found in stamps.items()}
        for device_id, births in self._births_proven.items():
            for b in births:
                stamps.setdefault(device_id, set()).update(map(_timestamp_of, b.values()))
        self._stamps = stamps

    def overlaps(self, device_id: str, timestamps: Iterable[int]) -> bool:
        """Values of the device with one of these CNC timestamps may be recorded (False: none is)."""
        stamps = self._stamps.get(device_id)
        return stamps is not None and not stamps.isdisjoint(timestamps)

    def fresh_rows(self, device_id: str, rows: Sequence[Sequence[Any]]) -> list[Sequence[Any]] | None:
        """`fresh` for a spool row's parsed rows [name, value, type, ts, quality] whose timestamps only births
        may share: the rows the births did not carry (counting the others in `skipped`), no Sample built.
        None when a recorded key may match (a timestamp of its keys) or a row's name or timestamp is not as
        written (then `fresh` decides, on samples). A row whose timestamps overlap the births' was sent one
        by one as samples before: ~11 % of a 1,000-machine backlog, kept until its step was acknowledged."""
        key_stamps = self._key_stamps.get(device_id)
        for row in rows:
            if type(row[0]) is not str or type(row[3]) is not int or (key_stamps and row[3] in key_stamps):
                return None
        births = self._births_of(device_id)
        out = [row for row in rows if not _carried(births, row[0], row[3], row[1])]
        self.skipped += len(rows) - len(out)
        return out

    def _born(self, device_id: str, s: Sample) -> bool:
        """A birth on this connection, or a proven one, carried this very value."""
        return _carried(self._births_of(device_id), s.name, s.timestamp_ms, s.value)

    def _births_of(self, device_id: str) -> list[_SlotBirth]:
        """The device's births, proven and on this connection."""
        return [*self._births_proven.get(device_id, ()), *(b for _, b in self._births_sent.get(device_id, ()))]

    def fresh(self, device_id: str, samples: Sequence[Sample]) -> Sequence[Sample]:
        """The samples the host does not have yet (counting the others in `skipped`); `samples` itself when
        none of their timestamps was ever recorded for the device (no key is built then)."""
        if not self.overlaps(device_id, map(_timestamp_of, samples)):
            return samples
        proven, sent = self._proven, self._sent
        born = device_id in self._births_proven or device_id in self._births_sent
        out = []
        for s in samples:
            key = _key(device_id, s)
            if key not in proven and key not in sent and not (born and self._born(device_id, s)):
                out.append(s)
        self.skipped += len(samples) - len(out)
        return out
