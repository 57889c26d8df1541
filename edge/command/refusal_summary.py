"""One audit line for a command refused before anything reached the CNC, however many writes it held.

A DCMD with 5,000 unknown metric names used to write 5,000 audit lines (2.3 MB); a refused command is now
one line: the first refusal (its code, target, id and message) plus a bounded count of the rest by code,
with a few example names. The counters still count every write.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

from edge.command.audit import AuditRecord, utc_now
from edge.command.errors import ErrorCode
from edge.command.requests import RequestItem
from edge.command.results import WriteResult

EXAMPLES_PER_CODE = 3
MAX_NAME_CHARS = 64
MAX_IDS = 64


def summary_record(machine_id: str, source_format: str, topic: str, items: Sequence[RequestItem],
                   results: Sequence[WriteResult]) -> AuditRecord:
    """The audit line of a command none of whose writes was sent (refused or skipped, in one)."""
    pairs = list(zip(items, results, strict=True))
    first_item, first = next(((i, r) for i, r in pairs if r.code is not ErrorCode.SKIPPED), pairs[0])
    message = first.message or ""
    if len(pairs) > 1:
        message += f" [{_rest(pairs)}]"
    return AuditRecord(
        time=utc_now(), machine=machine_id, source=source_format, topic=topic, client_id=first_item.client,
        request_id=_ids(items) if len(items) > 1 else first_item.id,
        target=first.op.text if first.op is not None else first_item.target_text,
        value=first.op.reply_value() if first.op is not None else first_item.requested,
        old=None, new=None, outcome=first.outcome, message=message)


def _rest(pairs: Sequence[tuple[RequestItem, WriteResult]]) -> str:
    """`64 writes, none sent: unknown_metric x63 ('a', 'b', 'c', ...), skipped x1`."""
    by_code: Counter[str] = Counter(result.outcome for _item, result in pairs)
    examples: dict[str, list[str]] = {}
    for item, result in pairs:
        names = examples.setdefault(result.outcome, [])
        name = result.op.text if result.op is not None else item.target_text
        if name is not None and len(names) < EXAMPLES_PER_CODE:
            names.append(repr(name[:MAX_NAME_CHARS]))
    parts = []
    for code, count in by_code.most_common():
        shown = examples.get(code, [])
        more = ", ..." if count > len(shown) and shown else ""
        parts.append(f"{code} x{count}" + (f" ({', '.join(shown)}{more})" if shown else ""))
    return f"{len(pairs)} writes in this command, none sent: " + "; ".join(parts)


def _ids(items: Sequence[RequestItem]) -> list[object] | None:
    """The ids a list carried (the first MAX_IDS), so the line can be matched to the request; None if none."""
    ids = [item.id for item in items if item.id is not None]
    return ids[:MAX_IDS] or None
