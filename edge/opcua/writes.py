"""What the OPC UA server needs from the command layer, and how its outcome reads as a StatusCode.

The server never decides whether a write may happen: it hands (machine, metric, value, who) to the
`WriteHandler` the service layer gives it — the same path JSON commands and Sparkplug DCMD take (policy,
bounds on the number the CNC holds, audit, read-back) — and answers the status matching the outcome.
Pure: no asyncua, no edge.command (the codes are the command layer's public reply codes, docs/writes.md).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class WriteOutcome:
    """One write's result as the command layer reports it: ok, or its reply code and message."""

    ok: bool
    code: str | None = None
    message: str | None = None


# (machine id, metric name, value, who wrote it: "user@client address") -> outcome
WriteHandler = Callable[[str, str, object, str], Awaitable[WriteOutcome]]
# (machine id, metric name) -> whether the write policy covers the metric's target (the node's AccessLevel)
WritableCheck = Callable[[str, str], bool]

# The command layer's reply codes (edge.command.errors.ErrorCode values) -> OPC UA StatusCode names.
STATUS_BY_CODE: dict[str, str] = {
    # refused before anything reached the CNC
    "malformed": "BadTypeMismatch",
    "wrong_type": "BadTypeMismatch",
    "payload_too_large": "BadInvalidArgument",
    "unknown_machine": "BadNodeIdUnknown",
    "unknown_metric": "BadNotWritable",
    "unknown_path": "BadNodeIdUnknown",
    "invalid_target": "BadNotWritable",
    "disabled": "BadUserAccessDenied",
    "not_allowed": "BadUserAccessDenied",
    "out_of_bounds": "BadOutOfRange",
    "rate_limited": "BadTooManyOperations",
    "queue_full": "BadResourceUnavailable",
    "skipped": "BadInvalidState",
    "shutting_down": "BadShutdown",
    # answered by the CNC or the session
    "access_denied": "BadNotWritable",
    "out_of_range": "BadOutOfRange",
    "not_supported": "BadNotSupported",
    "length": "BadInvalidArgument",
    "busy": "BadResourceUnavailable",
    "cnc_error": "BadDeviceFailure",
    "unavailable": "BadCommunicationError",
    "timeout": "BadTimeout",
    "not_applied": "BadTimeout",
    # the gateway failed handling the write (a bug, logged with its traceback)
    "internal_error": "BadInternalError",
}
UNKNOWN_CODE_STATUS = "BadInternalError"


def status_for(outcome: WriteOutcome) -> str:
    """The StatusCode name a client gets for this outcome."""
    if outcome.ok:
        return "Good"
    return STATUS_BY_CODE.get(outcome.code or "", UNKNOWN_CODE_STATUS)
