"""The binary encoding (OPC 10000-6 §5.2) of the one message the server sends thousands of times a second:
a DataChangeNotification of the gateway's own DataValues.

asyncua encodes a DataValue through its generic dataclass serializer (a closure per field, an optional-field
mask computed by getattr, datetimes converted per call): about 18 us a value, most of the server's CPU with
a client subscribed to every metric. The gateway's values are always scalars of a built-in type with a
status and both timestamps, so one precompiled struct encodes each in one call, from the timestamps the
value was built with (epoch ms -> 100 ns ticks, no datetime arithmetic). The bytes are asyncua's own
(tests/unit/opcua/test_encoding.py compares them); any other DataValue goes through asyncua.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Collection, Sequence
from functools import partial

from asyncua import ua
from asyncua.ua.ua_binary import get_string_encoding, struct_to_binary

# OPC UA DateTime: 100 ns ticks since 1601-01-01 UTC; the Unix epoch is this many ms after it
WIN_EPOCH_OFFSET_MS = 11_644_473_600_000
_TICKS_PER_MS = 10_000
_MAX_TICKS = 2**63 - 1  # DateTime at or after 9999-12-31 23:59:59 is encoded as the Int64 maximum
_MAX_MS = 253_402_300_799_000  # 9999-12-31 23:59:59 UTC in epoch ms
MIN_MS = -WIN_EPOCH_OFFSET_MS  # epoch ms strictly between MIN_MS and MAX_MS: ticks = (ms + offset) * 10,000
MAX_MS = _MAX_MS
TICKS_PER_MS = _TICKS_PER_MS

# DataValue encoding mask (§5.2.2.17): Value, StatusCode, SourceTimestamp, ServerTimestamp
_ALL_FIELDS = 0x01 | 0x02 | 0x04 | 0x08
_STATUS_AND_TIMES = struct.Struct("<Iqq")
_EMPTY_DIAGNOSTICS = struct.pack("<i", 0)
_COUNT = struct.Struct("<i")
_HANDLE = struct.Struct("<I")
_DATA_CHANGE_TYPE = ua.typeid_by_extension_objects[ua.DataChangeNotification]

# fixed-size scalar variant types -> the struct format of their value
_FIXED: dict[ua.VariantType, str] = {
    ua.VariantType.Boolean: "?", ua.VariantType.SByte: "b", ua.VariantType.Byte: "B", ua.VariantType.Int16: "h",
    ua.VariantType.UInt16: "H", ua.VariantType.Int32: "i", ua.VariantType.UInt32: "I", ua.VariantType.Int64: "q",
    ua.VariantType.UInt64: "Q", ua.VariantType.Float: "f", ua.VariantType.Double: "d",
}


def ticks(epoch_ms: int) -> int:
    """OPC UA DateTime ticks of an epoch-ms time, as asyncua encodes the equivalent aware datetime."""
    if epoch_ms <= -WIN_EPOCH_OFFSET_MS:
        return 0
    if epoch_ms >= _MAX_MS:
        return _MAX_TICKS
    return (epoch_ms + WIN_EPOCH_OFFSET_MS) * _TICKS_PER_MS


Encoder = Callable[[object, int, int, int], bytes]  # (value, status, source ticks, server ticks) -> bytes


def _fixed_encoder(vtype: ua.VariantType, fmt: str) -> Encoder:
    # the struct's pack with the mask and variant type bound: a call into C, no Python frame per value
    return partial(struct.Struct(f"<BB{fmt}Iqq").pack, _ALL_FIELDS, vtype.value)


def _string_encoder() -> Encoder:
    # Primitives.String.pack's bytes (the string in asyncua's configured encoding, surrogates escaped, after its
    # Int32 length) without its three Python calls per value: the value is always a str here (edge.opcua.values)
    head = bytes((_ALL_FIELDS, ua.VariantType.String.value))
    length, tail, join = _COUNT.pack, _STATUS_AND_TIMES.pack, b"".join

    def encode(value: object, status: int, source: int, server: int) -> bytes:
        data = value.encode(get_string_encoding(), "surrogateescape")  # type: ignore[attr-defined]
        return join((head, length(len(data)), data, tail(status, source, server)))

    return encode


def _datetime_encoder() -> Encoder:
    head = struct.Struct("<BBq").pack
    mask, variant, tail = _ALL_FIELDS, ua.VariantType.DateTime.value, _STATUS_AND_TIMES.pack

    def encode(value: object, status: int, source: int, server: int) -> bytes:
        return head(mask, variant, ua.datetime_to_win_epoch(value)) + tail(status, source, server)

    return encode


def _null_encoder() -> Encoder:
    pack = struct.Struct("<BBIqq").pack
    mask, variant = _ALL_FIELDS, ua.VariantType.Null.value

    def encode(value: object, status: int, source: int, server: int) -> bytes:
        return pack(mask, variant, status, source, server)

    return encode


ENCODERS: dict[ua.VariantType, Encoder] = {vtype: _fixed_encoder(vtype, fmt) for vtype, fmt in _FIXED.items()}
ENCODERS[ua.VariantType.String] = _string_encoder()
ENCODERS[ua.VariantType.DateTime] = _datetime_encoder()
ENCODERS[ua.VariantType.Null] = _null_encoder()


def data_value_bytes(value: ua.DataValue) -> bytes:
    """The DataValue's encoding: precomputed by the gateway's values (edge.opcua.values), else asyncua's."""
    encoded = getattr(value, "encoded", None)
    if encoded is not None:
        return encoded
    return struct_to_binary(value)


def data_change_body(notifications: Sequence[tuple[int, ua.DataValue]]) -> bytes:
    """A DataChangeNotification's body: (client handle, DataValue) of each item, no diagnostics."""
    handle = _HANDLE.pack
    parts = [_COUNT.pack(len(notifications))]
    parts.extend(handle(client_handle) + data_value_bytes(value) for client_handle, value in notifications)
    parts.append(_EMPTY_DIAGNOSTICS)
    return b"".join(parts)


def handle_prefix(client_handle: int) -> bytes:
    """A MonitoredItemNotification's first field; `handle_prefix(h) + value.encoded` is the whole notification."""
    return _HANDLE.pack(client_handle)


def note_bytes(note: object) -> bytes:
    """One queued change as a MonitoredItemNotification's bytes: already bytes (the gateway's own), a
    (client handle, DataValue) pair, or asyncua's MonitoredItemNotification."""
    if isinstance(note, bytes):
        return note
    if isinstance(note, tuple):
        client_handle, value = note
    else:
        client_handle, value = note.ClientHandle, note.Value  # type: ignore[attr-defined]
    return _HANDLE.pack(client_handle) + data_value_bytes(value)


def data_change_of_notes(queues: Collection[object]) -> ua.ExtensionObject:
    """The DataChangeNotification of every item's queued changes, in order: an item's one bytes notification
    queued bare (edge.opcua.subscriptions.enqueue), or a list of them (`note_bytes`). When every item has one
    bare notification (the usual case) the body is one join, with no Python step per notification."""
    try:
        body = b"".join(queues)  # type: ignore[arg-type]
        count = len(queues)
    except TypeError:  # an item with several changes, or one not pre-encoded (an item on asyncua's path)
        notes = [note_bytes(note) for queued in queues
                 for note in ((queued,) if type(queued) is bytes else queued)]  # type: ignore[attr-defined]
        body = b"".join(notes)
        count = len(notes)
    return ua.ExtensionObject(TypeId=_DATA_CHANGE_TYPE, Body=_COUNT.pack(count) + body + _EMPTY_DIAGNOSTICS)


def data_change_notification(notifications: Sequence[tuple[int, ua.DataValue]]) -> ua.ExtensionObject:
    """The notification as an already-encoded ExtensionObject: asyncua writes its type id and body as they are,
    which is byte for byte what it writes for the equivalent DataChangeNotification."""
    return ua.ExtensionObject(TypeId=_DATA_CHANGE_TYPE, Body=data_change_body(notifications))
