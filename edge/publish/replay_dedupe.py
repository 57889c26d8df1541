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
A replayed row's samples are forgotten once the row is acknowledged (it cannot come back), so the record
stays the size of the births, the unconfirmed live batches and one replay batch; everything is forgotten
when the spool has nothing left to replay.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence

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


def _key(device_id: str, sample: Sample) -> Key:
    return device_id, sample.name, sample.timestamp_ms, value_key(sample.value)


class DeliveredValues:
    """(device, metric, CNC timestamp, value) of what the host has (proven) or was sent on this connection."""

    def __init__(self, limit: int = DEFAULT_LIMIT) -> None:
        self._proven: set[Key] = set()
        self._sent: dict[Key, int] = {}  # key -> the record call that added it (a barrier proves earlier ones)
        self._calls = 0
        self._limit = limit
        self.skipped = 0  # replayed samples left out as duplicates, since the process started

    def __len__(self) -> int:
        return len(self._proven) + len(self._sent)

    def record(self, device_id: str, samples: Iterable[Sample]) -> None:
        """These samples went out on the current connection (call after publishing them)."""
        if len(self) >= self._limit:
            return
        self._calls += 1
        call = self._calls
        for s in samples:
            self._sent.setdefault(_key(device_id, s), call)

    def mark(self) -> int:
        """Taken just before a barrier is published: it proves what was recorded up to here."""
        return self._calls

    def proven(self, mark: int) -> None:
        """The barrier published at `mark` on the current connection was acknowledged."""
        done = [key for key, call in self._sent.items() if call <= mark]
        self._proven.update(done)
        for key in done:
            del self._sent[key]

    def discard(self, device_id: str, samples: Iterable[Sample]) -> None:
        """These samples' rows left the spool (acknowledged): no replay can repeat them, keep no memory."""
        if not self._proven and not self._sent:
            return
        for s in samples:
            key = _key(device_id, s)
            self._sent.pop(key, None)
            self._proven.discard(key)

    def connection_lost(self) -> None:
        """What the old connection sent without proof may not have arrived."""
        self._sent = {}

    def forget(self) -> None:
        """The spool is empty: no replayed row can repeat any of it."""
        self._proven = set()
        self._sent = {}

    def fresh(self, device_id: str, samples: Sequence[Sample]) -> list[Sample]:
        """The samples the host does not have yet (counting the others in `skipped`)."""
        if not self._proven and not self._sent:
            return list(samples)
        proven, sent = self._proven, self._sent
        out = []
        for s in samples:
            key = _key(device_id, s)
            if key not in proven and key not in sent:
                out.append(s)
        self.skipped += len(samples) - len(out)
        return out
