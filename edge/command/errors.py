"""Reply codes of the write path, and the mapping from protocol errors to them.

Every write that does not succeed ends with one of these codes in its reply (JSON) and its audit line
(JSON and DCMD). The list is part of the public contract (docs/writes.md); add, never rename.
"""

from __future__ import annotations

import enum

from edge.focas.errors import (
    AccessDenied,
    Busy,
    CncError,
    ConnectionLost,
    FocasError,
    FocasTimeout,
    LengthError,
    NotSupported,
    OutOfRange,
    ProtocolError,
)


class ErrorCode(enum.StrEnum):
    """Why a write did not happen (or may not have)."""

    # refused before anything reached the CNC
    MALFORMED = "malformed"  # not JSON, not the request schema
    PAYLOAD_TOO_LARGE = "payload_too_large"
    UNKNOWN_MACHINE = "unknown_machine"
    UNKNOWN_METRIC = "unknown_metric"  # DCMD metric with no write target behind it
    UNKNOWN_PATH = "unknown_path"  # `@N` / "path": N beyond the paths configured for the machine
    DISABLED = "disabled"
    INVALID_TARGET = "invalid_target"
    NOT_ALLOWED = "not_allowed"
    WRONG_TYPE = "wrong_type"
    OUT_OF_BOUNDS = "out_of_bounds"
    RATE_LIMITED = "rate_limited"
    QUEUE_FULL = "queue_full"
    SKIPPED = "skipped"  # an earlier write of the same request failed
    SHUTTING_DOWN = "shutting_down"
    # answered by the CNC or the session
    ACCESS_DENIED = "access_denied"
    OUT_OF_RANGE = "out_of_range"
    NOT_SUPPORTED = "not_supported"
    LENGTH = "length"
    BUSY = "busy"
    CNC_ERROR = "cnc_error"
    UNAVAILABLE = "unavailable"  # no CNC session within the reconnect deadline
    TIMEOUT = "timeout"  # no answer, and the re-read could not tell whether the write took
    NOT_APPLIED = "not_applied"  # no answer; the re-read shows the write did not take
    # the gateway itself failed while handling the command (a bug: its log has the traceback)
    INTERNAL_ERROR = "internal_error"


class CommandRefused(Exception):
    """A write that will not be (or was not) carried out, with its reply code."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message


def code_for(error: FocasError) -> ErrorCode:
    """The reply code for an error the session raised (most specific class first)."""
    if isinstance(error, AccessDenied):
        return ErrorCode.ACCESS_DENIED
    if isinstance(error, OutOfRange):
        return ErrorCode.OUT_OF_RANGE
    if isinstance(error, NotSupported):
        return ErrorCode.NOT_SUPPORTED
    if isinstance(error, LengthError):
        return ErrorCode.LENGTH
    if isinstance(error, Busy):
        return ErrorCode.BUSY
    if isinstance(error, FocasTimeout):
        return ErrorCode.TIMEOUT
    if isinstance(error, ConnectionLost | ProtocolError):
        return ErrorCode.UNAVAILABLE
    if isinstance(error, CncError):
        return ErrorCode.CNC_ERROR
    return ErrorCode.CNC_ERROR


def refused_by_cnc(error: FocasError) -> CommandRefused:
    return CommandRefused(code_for(error), str(error))
