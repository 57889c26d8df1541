"""The outcome of one write and the JSON reply built from it.

Reply (one object per write; a list request gets a list, in request order):

    {"id": "42", "ok": true, "target": "pmc:R100.3", "error": null, "value_read_back": true,
     "cnc_time": "2024-05-01T12:00:00.123Z"}
    {"id": "43", "ok": false, "target": "param:1815/1", "error": {"code": "access_denied", "message": "..."},
     "value_read_back": null, "cnc_time": null}
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from edge.command.errors import CommandRefused, ErrorCode
from edge.command.requests import WriteOp


@dataclass(frozen=True, slots=True)
class WriteResult:
    """What happened to one write: ok with the value read back, or a code; `old` for the audit line."""

    op: WriteOp | None
    ok: bool
    code: ErrorCode | None = None
    message: str | None = None
    old: object = None
    read_back: object = None
    cnc_time_ms: int | None = None
    note: str | None = None

    @classmethod
    def refused(cls, op: WriteOp | None, refusal: CommandRefused, old: object = None) -> WriteResult:
        return cls(op, False, refusal.code, refusal.message, old=old)

    @classmethod
    def skipped(cls, op: WriteOp | None, failed_index: int) -> WriteResult:
        return cls(op, False, ErrorCode.SKIPPED, f"not attempted: write {failed_index} of this request failed")

    @property
    def outcome(self) -> str:
        return "ok" if self.ok else str(self.code)


def iso_ms(epoch_ms: int | None) -> str | None:
    if epoch_ms is None:
        return None
    moment = datetime.fromtimestamp(epoch_ms / 1000, UTC)
    return moment.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def reply(request_id: object, target_text: str | None, result: WriteResult) -> dict[str, Any]:
    body: dict[str, Any] = {
        "id": request_id,
        "ok": result.ok,
        "target": result.op.text if result.op is not None else target_text,
        "error": None if result.ok else {"code": str(result.code), "message": result.message},
        "value_read_back": finite(result.read_back),
        "cnc_time": iso_ms(result.cnc_time_ms),
    }
    if result.note:
        body["note"] = result.note
    return body


def finite(value: object) -> object:
    """JSON has no NaN/Infinity (the publisher encodes strictly): a CNC's NaN float reads back as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def request_error(code: ErrorCode, message: str) -> dict[str, Any]:
    """The reply to a request refused as a whole (too large, not JSON): no id could be read."""
    return {"id": None, "ok": False, "target": None, "error": {"code": str(code), "message": message},
            "value_read_back": None, "cnc_time": None}
