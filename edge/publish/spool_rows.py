"""The spool's row body: a held batch as compact JSON rows [name, value, type, ts, quality], and its reading.

A 1,000-machine outage of 60 s is 60,000 rows to replay in 6 s, about 150,000 values a second beside the
live ticks. So the Sparkplug replay takes a row only parsed (one C call) and shaped, and encodes it straight
to DATA (edge.publish.node.historical_rows); its samples are built when asked for (the dedupe, a row the
fast path cannot read). The JSON replay, a message per value, takes samples.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from operator import itemgetter
from typing import Literal

from edge.samples import MetricType, Quality, Sample, new_sample

Format = Literal["sparkplug", "json"]
SampleKind = Literal["data", "events"]
Row = list  # [name: str, value, type: MetricType value, timestamp_ms: int, quality: int], as JSON parsed it

# The enum members by their stored values: a dict lookup per sample instead of an enum call (replay decodes
# every spooled sample; an unknown value falls through to the enum, which says what is wrong).
_TYPES: dict[object, MetricType] = {t.value: t for t in MetricType}
_QUALITIES: dict[object, Quality] = {int(q): q for q in Quality}
_LIST = {list}
_ROW_LENGTH = {5}
TIMESTAMP = itemgetter(3)
# json.loads' own scanner (C), called on the body's text without loads' encoding sniffing, whitespace regexes
# and exception wrapping: a third of a replayed row's parse. Only for a body as encode_samples writes it
# (`_parse`); anything else goes through json.loads.
_scan = json.JSONDecoder().scan_once  # type: ignore[attr-defined]  # set in its __init__: the C scanner


def encode_samples(samples: Sequence[Sample]) -> bytes:
    """Samples as compact JSON rows [name, value, type, ts, quality]; unknown value types become text."""
    rows = [[s.name, s.value, s.type.value, s.timestamp_ms, int(s.quality)] for s in samples]
    return json.dumps(rows, separators=(",", ":"), default=str).encode("utf-8")


def decode_samples(body: bytes, historical: bool = False) -> list[Sample]:
    """The inverse of encode_samples, the samples marked `historical` (what the replay sends); ValueError
    (with what came) for a body that is not one."""
    try:
        return samples_of(json.loads(body), historical)
    except (TypeError, ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"spool row: expected a JSON list of [name, value, type, ts, quality], "
                         f"got {body[:60]!r}: {exc}") from exc


def samples_of(rows: list[Row], historical: bool) -> list[Sample]:
    """Parsed rows as Samples (edge.samples.new_sample: a frozen dataclass's __init__ is four times the cost);
    TypeError or ValueError for a row that is not one."""
    out: list[Sample] = []
    append = out.append
    for name, value, kind, ts, quality in rows:
        append(new_sample(name if type(name) is str else str(name), value, _TYPES.get(kind) or MetricType(kind),
                          ts if type(ts) is int else int(ts), _QUALITIES.get(quality) or Quality(int(quality)),
                          historical))
    return out


def read_entry(row_id: int, fmt: Format, device_id: str, kind: SampleKind, body: bytes, *,
               lazy: bool = False) -> SpoolEntry:
    """A stored row for the replay, its samples read now (ValueError for a body that is not one), or with
    `lazy` when asked for: the entry keeps the body, the caller reads its `rows()` or `samples` and reports
    a row it cannot read (edge.publish.spool.DiskSpool.unreadable)."""
    if lazy:
        return SpoolEntry(row_id, fmt, device_id, kind, body=body)
    return SpoolEntry(row_id, fmt, device_id, kind, decode_samples(body, historical=True))


def _shaped(rows: list[object]) -> bool:
    return set(map(type, rows)) == _LIST and set(map(len, rows)) == _ROW_LENGTH  # type: ignore[arg-type]


def _parse(body: bytes) -> object:
    """json.loads(body), faster for a body as encode_samples writes it: ASCII JSON that starts with "[[" (no
    byte-order mark, no NUL: loads reads it as UTF-8) and ends where the value ends. The scanner's result is
    the one loads returns (loads is this scanner after a decode and a whitespace skip); a body it does not
    take whole, or at all, goes through json.loads for its value or its error."""
    if body.startswith(b"[["):
        try:
            text = body.decode("utf-8", "surrogatepass")
            rows, end = _scan(text, 0)
        except (StopIteration, ValueError):
            pass
        else:
            if end == len(text):
                return rows
    return json.loads(body)


class SpoolEntry:
    """One held batch with its row id (the replay order and the ack key): its `samples`, marked historical
    (the batch is replayed as such), or its stored body, read on demand as `rows()` or `samples`."""

    __slots__ = ("_body", "_samples", "device_id", "fmt", "id", "kind")

    def __init__(self, id: int, fmt: Format, device_id: str, kind: SampleKind,
                 samples: list[Sample] | None = None, *, body: bytes | None = None) -> None:
        if (samples is None) == (body is None):
            raise ValueError("a spool entry is given its samples or its stored body, one of the two")
        self.id = id
        self.fmt: Format = fmt
        self.device_id = device_id
        self.kind: SampleKind = kind
        self._body = body
        self._samples = samples

    @property
    def samples(self) -> list[Sample]:
        """Its samples, read from the body on first use (ValueError for a body that is not a row)."""
        if self._samples is None:
            assert self._body is not None
            self._samples = decode_samples(self._body, historical=True)
        return self._samples

    def rows(self) -> list[Row] | None:
        """The body parsed, when it is shaped as encode_samples writes it (a list of five-element lists;
        the columns are the caller's to check); None otherwise (read `samples`). Parsed on each call, not
        kept: a replay step holds thousands of entries."""
        if self._body is None:
            return None
        try:
            rows = _parse(self._body)
        except (ValueError, UnicodeDecodeError):
            return None
        return rows if type(rows) is list and (not rows or _shaped(rows)) else None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SpoolEntry):
            return NotImplemented
        return (self.id, self.fmt, self.device_id, self.kind, self.samples) == \
            (other.id, other.fmt, other.device_id, other.kind, other.samples)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"SpoolEntry(id={self.id}, fmt={self.fmt!r}, device_id={self.device_id!r}, kind={self.kind!r})"
