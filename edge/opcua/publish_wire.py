"""The binary encoding (OPC 10000-6 §5.2, 10000-4 §5.14.5) of the Publish request a subscribed client sends
every publishing interval and of the Publish response that answers it, written directly.

asyncua decodes a PublishRequest through its generic deserializer (the RequestHeader's datetime, a dataclass
per acknowledgement) and encodes a PublishResponse through its generic serializer (a closure per field of
five nested structures, a datetime converted per call): 10-15 us each on a fast host, 50-85 us on a slow
one, 50 times a second with a client at the gateway's 20 ms publishing interval. Here:

- `publish_request` reads what the server uses of a Publish request: the request handle and timeout hint
  (a `PublishHeader`), and the (subscription id, sequence number) of each acknowledgement. An encoding it
  does not expect (an ExpandedNodeId's flags on the session token, an AdditionalHeader with a body, a short
  message) returns None: the caller then decodes it with asyncua, which answers what it cannot read.
- `publish_response` writes the PublishResponse of a PublishResult: its header, the available sequence
  numbers, the NotificationMessage with each notification's bytes (the gateway's data changes are already
  an encoded ExtensionObject body, edge.opcua.encoding; another notification goes through asyncua's
  ExtensionObject encoder), the acknowledgement results and no diagnostics. Anything else (diagnostics,
  a field of a type asyncua would warn about) is encoded by asyncua whole.

The bytes are asyncua's own (tests/unit/opcua/test_publish_wire.py compares both directions with
`struct_to_binary`/`struct_from_binary`); the constant parts are taken from asyncua's encoding at import.
"""

from __future__ import annotations

import struct
import time
from typing import Any

from asyncua import ua
from asyncua.ua.ua_binary import extensionobject_to_binary, nodeid_to_binary, struct_to_binary

from edge.opcua.values import WIN_EPOCH_US

# a Publish request's type id, FourByte-encoded as every client we know sends it (a Numeric one: asyncua's path)
PUBLISH_TYPE = nodeid_to_binary(ua.FourByteNodeId(ua.ObjectIds.PublishRequest_Encoding_DefaultBinary))
_RESPONSE_TYPE = nodeid_to_binary(ua.FourByteNodeId(ua.ObjectIds.PublishResponse_Encoding_DefaultBinary))
_U8 = struct.Struct("<B").unpack_from
_U16 = struct.Struct("<H").unpack_from
_I32 = struct.Struct("<i").unpack_from
_AFTER_TOKEN = struct.Struct("<qIIi")  # Timestamp, RequestHandle, ReturnDiagnostics, AuditEntryId's length
_TIMEOUT_AND_NO_HEADER = struct.Struct("<I3s")  # TimeoutHint, AdditionalHeader (when null: 3 zero bytes)
_NULL_EXTENSION_OBJECT = b"\x00\x00\x00"
_ACK = struct.Struct("<II")
# size of a NodeId's identifier after its encoding byte, for the fixed-size encodings (§5.2.2.9)
_FIXED_IDENTIFIER = {0x00: 1, 0x01: 3, 0x02: 6, 0x04: 18}
_STRING_IDENTIFIERS = (0x03, 0x05)  # namespace (UInt16), then an Int32 length and the bytes

_INT32 = struct.Struct("<i").pack
_UINT32 = struct.Struct("<I").pack
_HEAD = struct.Struct("<qI").pack  # ResponseHeader's Timestamp, RequestHandle
# the rest of a default ResponseHeader: ServiceResult Good, no diagnostics, empty string table, no header
_HEADER_TAIL = struct_to_binary(ua.ResponseHeader())[12:]
_SEQUENCE_AND_TIME = struct.Struct("<Iq").pack
_BOOLEAN = struct.Struct("<?").pack
_EXTENSION_HEAD = struct.Struct("<Bi").pack  # encoding byte (0x01: a body), the body's length
_NO_DIAGNOSTICS = _INT32(0)
_NULL_LIST = _INT32(-1)
_type_ids: dict[ua.NodeId, bytes] = {}  # an ExtensionObject's TypeId -> its encoding


class PublishHeader:
    """The fields of a Publish request's RequestHeader the server reads (asyncua's PublishRequestData keeps it:
    its handle for the response, its timeout hint for a request left waiting)."""

    __slots__ = ("RequestHandle", "TimeoutHint")

    def __init__(self, request_handle: int, timeout_hint: int) -> None:
        self.RequestHandle = request_handle
        self.TimeoutHint = timeout_hint


def publish_request(data: bytes) -> tuple[PublishHeader, int, list[tuple[int, int]]] | None:
    """(header, bytes read up to the parameters, acknowledgements as (subscription id, sequence number)) of a
    Publish request's message body `data` (type id first); None when it is not a Publish request or not in
    the encoding read here (asyncua decodes it then)."""
    if not data.startswith(PUBLISH_TYPE):
        return None
    try:
        pos = 4
        token = _U8(data, pos)[0]
        pos += 1
        size = _FIXED_IDENTIFIER.get(token)
        if size is not None:
            pos += size
        elif token in _STRING_IDENTIFIERS:
            length = _I32(data, pos + 2)[0]
            pos += 6 + max(length, 0)
        else:  # a Guid's 2 + 16 bytes are in _FIXED_IDENTIFIER; flags or another type: asyncua's
            return None
        _, handle, _, audit_length = _AFTER_TOKEN.unpack_from(data, pos)
        pos += 20 + max(audit_length, 0)
        timeout, additional = _TIMEOUT_AND_NO_HEADER.unpack_from(data, pos)
        if additional != _NULL_EXTENSION_OBJECT:
            return None
        pos += 7
        header_end = pos
        count = _I32(data, pos)[0]
        pos += 4
        acks = [_ACK.unpack_from(data, pos + 8 * i) for i in range(count)]
    except struct.error:
        return None
    return PublishHeader(handle, timeout), header_end, acks


def now_ticks() -> int:
    """The current time as asyncua encodes `datetime.now(timezone.utc)` (microsecond resolution)."""
    return (time.time_ns() // 1000 + WIN_EPOCH_US) * 10  # as the address space stamps a batch's ServerTimestamp


def _notification(obj: Any) -> bytes:
    if type(obj) is ua.ExtensionObject:
        body = obj.Body
        type_id = _type_ids.get(obj.TypeId)
        if type_id is None:
            type_id = _type_ids[obj.TypeId] = nodeid_to_binary(obj.TypeId)
        if body is None:
            return type_id + b"\x00"
        return type_id + _EXTENSION_HEAD(1, len(body)) + body
    return extensionobject_to_binary(obj)


def _u32_list(values: Any) -> bytes | None:
    if type(values) is not list and type(values) is not tuple:
        return None
    return _INT32(len(values)) + struct.pack(f"<{len(values)}I", *values)


def publish_response(request_handle: int, result: ua.PublishResult, timestamp: int | None = None) -> bytes:
    """`struct_to_binary` of a PublishResponse whose ResponseHeader is a default one with `request_handle` and
    `timestamp` (ticks, default now) and whose Parameters are `result`."""
    message = result.NotificationMessage
    available = _u32_list(result.AvailableSequenceNumbers)
    statuses = result.Results
    codes = None if type(statuses) is not list else _u32_list([status.value for status in statuses])
    if available is None or codes is None or result.DiagnosticInfos or type(message.NotificationData) is not list:
        response = ua.PublishResponse(Parameters=result)
        response.ResponseHeader.RequestHandle = request_handle
        if timestamp is not None:
            response.ResponseHeader.Timestamp = ua.win_epoch_to_datetime(timestamp)
        return struct_to_binary(response)
    notifications = message.NotificationData
    return b"".join((
        _RESPONSE_TYPE,
        _HEAD(now_ticks() if timestamp is None else timestamp, request_handle),
        _HEADER_TAIL,
        _UINT32(result.SubscriptionId),
        available,
        _BOOLEAN(result.MoreNotifications),
        _SEQUENCE_AND_TIME(message.SequenceNumber, ua.datetime_to_win_epoch(message.PublishTime)),
        _INT32(len(notifications)),
        *map(_notification, notifications),
        codes,
        _NO_DIAGNOSTICS if result.DiagnosticInfos is not None else _NULL_LIST,
    ))
