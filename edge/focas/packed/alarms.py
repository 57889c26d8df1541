"""Alarms on the packed surface: the history (ODBALMHIS, 0x0F1A) and the active alarms (0x4004).

ODBALMHIS answers ``num_alm`` first, negative meaning a CNC error, and its decoder never raises (seed):
`decode_alarm_history` turns an error into an empty list. A caller must not take that list for "no
history", so `parse_alarm_history` walks the same answer and says what the list cannot: the status a
negative num_alm carries, and whether the list ended early. The client reads history through
`decode_alarm_history_response`, which raises those as errors, so a failing history read is a counted
error of that function rather than an empty list (issue 24). The active-alarm read is ours and answers
the status word first like every other read we define.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

from edge.focas.errors import ProtocolError
from edge.focas.model import ActiveAlarm, AlarmHistoryEntry
from edge.focas.packed.commands import I16, Command, body_after_status, status_error

# ---- ODBALMHIS (0x0F1A) --------------------------------------------------------------------------------
# Request: i16 depth, clamped to 1..250. Response: i16 num_alm (< 0: CNC error), then num_alm entries of
# ten i16 (year, month, day, hour, minute, second, axis_no, alm_type, alm_no, msg_len), msg_len ASCII
# bytes, and zero padding so each entry block is a multiple of 4 bytes long (20 + msg_len + pad).
ALMHIS_MIN_DEPTH = 1
ALMHIS_MAX_DEPTH = 250
_ALMHIS_ENTRY = struct.Struct("<10h")


def clamp_depth(depth: int) -> int:
    return max(ALMHIS_MIN_DEPTH, min(ALMHIS_MAX_DEPTH, depth))


def encode_alarm_history_request(depth: int) -> bytes:
    return I16.pack(clamp_depth(depth))


def decode_alarm_history_request(payload: bytes) -> int:
    """Server side; a missing or odd request is read as the largest depth (clamping covers the rest)."""
    if len(payload) < 2:
        return ALMHIS_MAX_DEPTH
    return clamp_depth(I16.unpack_from(payload)[0])


def almhis_padding(msg_len: int) -> int:
    """Pad bytes after an entry's message so the block (20 + msg_len + pad) ends on a 4-byte boundary."""
    return -msg_len % 4


@dataclass(frozen=True, slots=True)
class AlarmHistoryRow:
    """One ODBALMHIS entry as raw fields: a bridge passes the CNC's date fields through unchecked (the
    decoder skips an impossible date), which a datetime could not carry."""

    year: int
    month: int
    day: int
    hour: int
    minute: int
    second: int
    axis_no: int
    alm_type: int
    alm_no: int
    message: bytes


def encode_alarm_history(entries: Sequence[AlarmHistoryEntry]) -> bytes:
    """ODBALMHIS for `entries` (newest first). Times are converted to UTC; sub-second parts are dropped."""
    rows = []
    for entry in entries:
        when = entry.occurred.astimezone(UTC) if entry.occurred.tzinfo else entry.occurred
        rows.append(AlarmHistoryRow(when.year, when.month, when.day, when.hour, when.minute, when.second,
                                    entry.axis_no, entry.alm_type, entry.alm_no,
                                    entry.message.encode("ascii", errors="replace")))
    return encode_alarm_history_rows(rows)


def encode_alarm_history_rows(rows: Sequence[AlarmHistoryRow]) -> bytes:
    """ODBALMHIS from raw rows (newest first), each block padded to a multiple of 4 from its start."""
    blocks = [I16.pack(len(rows))]
    for row in rows:
        blocks.append(_ALMHIS_ENTRY.pack(row.year, row.month, row.day, row.hour, row.minute, row.second,
                                         row.axis_no, row.alm_type, row.alm_no, len(row.message)))
        blocks.append(row.message + b"\x00" * almhis_padding(len(row.message)))
    return b"".join(blocks)


# A server's error travels as a negative num_alm. The CNC's own codes (positive EW_*) as -status, as the
# seed's "< 0 is a CNC error" and docs/packed-protocol.md §3.1 say (EW_FUNC -> -1); the library-side codes
# (negative EW_*: EW_SOCKET, EW_HANDLE, EW_BUSY ...) as status - LIBRARY_STATUS_OFFSET (EW_SOCKET -> -1016),
# so the two cannot be mistaken for each other (-1 would otherwise be EW_FUNC and EW_BUSY at once).
LIBRARY_STATUS_OFFSET = 1000


def encode_alarm_history_error(status: int) -> bytes:
    """A CNC error on 0x0F1A as a negative num_alm that `alarm_history_status` turns back into `status`."""
    if status < 0:
        return I16.pack(max(status - LIBRARY_STATUS_OFFSET, -32768))
    return I16.pack(-min(status, 32767) or -1)


def alarm_history_status(num_alm: int) -> int:
    """The EW status a num_alm carries: 0 for a count (>= 0), else the code encode_alarm_history_error sent."""
    if num_alm >= 0:
        return 0
    if num_alm < -LIBRARY_STATUS_OFFSET:
        return num_alm + LIBRARY_STATUS_OFFSET
    return -num_alm


@dataclass(frozen=True, slots=True)
class AlarmHistoryAnswer:
    """One ODBALMHIS answer walked in full: the entries, and what the seed's list leaves unsaid.

    status: the EW code of a negative num_alm (0 when it is a count); announced: num_alm itself;
    truncated: the payload is too short for num_alm's entries (or for num_alm), so the list ended early;
    skipped: entries dropped for an impossible date (the seed's rule: no stable key can be made for them).
    """

    entries: list[AlarmHistoryEntry]
    status: int = 0
    announced: int = 0
    truncated: bool = False
    skipped: int = 0


def parse_alarm_history(payload: bytes) -> AlarmHistoryAnswer:
    """The seed's error rules, and never an exception on a bad payload.

    num_alm < 0 -> no entries (its status kept); a malformed timestamp skips that entry only; an entry
    whose header or message runs past the payload (or has a negative msg_len) ends the list there
    (truncated). A final entry whose padding is missing is kept.
    """
    if len(payload) < 2:
        return AlarmHistoryAnswer([], truncated=True)
    (num_alm,) = I16.unpack_from(payload)
    if num_alm < 0:
        return AlarmHistoryAnswer([], alarm_history_status(num_alm), num_alm)
    entries: list[AlarmHistoryEntry] = []
    offset = 2
    skipped = 0
    for _ in range(num_alm):
        if offset + _ALMHIS_ENTRY.size > len(payload):
            return AlarmHistoryAnswer(entries, 0, num_alm, True, skipped)
        year, month, day, hour, minute, second, axis_no, alm_type, alm_no, msg_len = (
            _ALMHIS_ENTRY.unpack_from(payload, offset)
        )
        text_at = offset + _ALMHIS_ENTRY.size
        if msg_len < 0 or text_at + msg_len > len(payload):
            return AlarmHistoryAnswer(entries, 0, num_alm, True, skipped)
        message = payload[text_at : text_at + msg_len].decode("ascii", errors="replace")
        offset = text_at + msg_len + almhis_padding(msg_len)
        try:
            occurred = datetime(year, month, day, hour, minute, second, tzinfo=UTC)
        except ValueError:
            skipped += 1
            continue
        entries.append(AlarmHistoryEntry(occurred, axis_no, alm_type, alm_no, message))
    return AlarmHistoryAnswer(entries, 0, num_alm, False, skipped)


def decode_alarm_history(payload: bytes) -> list[AlarmHistoryEntry]:
    """The seed's decoder: the entries of `parse_alarm_history`, so an error or a short payload is []."""
    return parse_alarm_history(payload).entries


def decode_alarm_history_response(payload: bytes) -> list[AlarmHistoryEntry]:
    """The client's read of 0x0F1A: the entries, or the error the seed's decoder would hide.

    A negative num_alm raises its typed CncError (EW_SOCKET while the library host's CNC is unavailable,
    FunctionNotAvailable for a control without history ...); a payload too short for what num_alm
    announced raises ProtocolError, since publishing the entries that did arrive would move the history
    watermark past the ones that did not.
    """
    answer = parse_alarm_history(payload)
    error = status_error(answer.status, Command.RDALMHISTRY)
    if error is not None:
        raise error
    if answer.truncated:
        raise ProtocolError(f"cnc_rdalmhistry: {len(payload)}-byte answer ends before the {answer.announced} "
                            f"entries its num_alm announces")
    return answer.entries


# ---- active alarms (0x4004) ----------------------------------------------------------------------------
# Request: i16 max_count. Response body: i16 count, then per alarm i32 alm_no | i16 type | i16 axis |
# i16 msg_len | msg | pad to a 4-byte block (10 + msg_len + pad, padded like ODBALMHIS).
_ALMMSG_ENTRY = struct.Struct("<ihhh")


def encode_alarm_messages(alarms: Sequence[ActiveAlarm]) -> bytes:
    blocks = [I16.pack(len(alarms))]
    for alarm in alarms:
        message = alarm.message.encode("ascii", errors="replace")
        pad = -(_ALMMSG_ENTRY.size + len(message)) % 4
        blocks.append(_ALMMSG_ENTRY.pack(alarm.number, alarm.type, alarm.axis, len(message)))
        blocks.append(message + b"\x00" * pad)
    return b"".join(blocks)


def decode_alarm_messages_response(payload: bytes) -> list[ActiveAlarm]:
    body = body_after_status(payload, Command.RDALMMSG)
    if len(body) < 2:
        raise ProtocolError(f"cnc_rdalmmsg: expected an i16 count, got {len(body)} bytes")
    (count,) = I16.unpack_from(body)
    alarms: list[ActiveAlarm] = []
    offset = 2
    for index in range(count):
        if offset + _ALMMSG_ENTRY.size > len(body):
            raise ProtocolError(
                f"cnc_rdalmmsg: alarm {index} of {count} starts past the {len(body)}-byte body"
            )
        number, atype, axis, msg_len = _ALMMSG_ENTRY.unpack_from(body, offset)
        text_at = offset + _ALMMSG_ENTRY.size
        if msg_len < 0 or text_at + msg_len > len(body):
            raise ProtocolError(f"cnc_rdalmmsg: alarm {index} msg_len {msg_len} runs past the body")
        message = body[text_at : text_at + msg_len].decode("ascii", errors="replace")
        offset = text_at + msg_len + (-(_ALMMSG_ENTRY.size + msg_len) % 4)
        alarms.append(ActiveAlarm(number, atype, axis, message))
    return alarms
