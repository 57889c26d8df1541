"""A CreateMonitoredItems request's items decoded by one struct read each when they have the usual shape.

asyncua's generic decoder walks a MonitoredItemCreateRequest field by field through three nested structs, an
ExtensionObject and a NodeId (about 16 us an item on a fast host): most of the CPU a subscription of 10,000
items costs the server, ahead of creating the items (~5-8 us each). Nearly every client asks the same
shape: a NodeId of one of the four usual encodings, the Value attribute of the whole node (no index range,
no data encoding), no filter. `fast_items` reads that shape with one struct unpack after the NodeId, and
makes the same objects asyncua makes (tests/unit/opcua/test_item_decoding.py compares them); any other item
(a filter, an index range, an expanded or GUID NodeId, too few bytes) is left untouched to asyncua's decoder.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from asyncua import ua
from asyncua.ua.ua_binary import get_string_encoding

# after the NodeId: AttributeId, IndexRange length (-1: null), DataEncoding's namespace and name length
# (0, -1: null), MonitoringMode, ClientHandle, SamplingInterval, the filter's type id (a two-byte NodeId:
# encoding 0, id 0) and its body encoding (0: none), QueueSize, DiscardOldest
_TAIL = struct.Struct("<IiHiIIdBBBIB")
_STRING_ID = struct.Struct("<Hi")  # a string NodeId's namespace and length
_NUMERIC_ID = struct.Struct("<HI")
_FOUR_BYTE_ID = struct.Struct("<BH")
_MODES = {mode.value: mode for mode in ua.MonitoringMode}
_NUMERIC, _FOUR_BYTE, _TWO_BYTE = ua.NodeIdType.Numeric, ua.NodeIdType.FourByte, ua.NodeIdType.TwoByte

_Decoder = Callable[[Any], Any]


def fast_items(generic: _Decoder) -> _Decoder:
    """A decoder of MonitoredItemCreateRequests reading the usual shape itself, `generic` (asyncua's) the rest."""
    item, read_value_id, parameters = ua.MonitoredItemCreateRequest, ua.ReadValueId, ua.MonitoringParameters
    node_id, qualified_name, extension = ua.NodeId, ua.QualifiedName, ua.ExtensionObject
    tail, string_id, numeric_id, four_byte_id, modes = (_TAIL.unpack_from, _STRING_ID.unpack_from,
                                                        _NUMERIC_ID.unpack_from, _FOUR_BYTE_ID.unpack_from, _MODES)
    tail_size = _TAIL.size

    def decode(buffer: Any) -> ua.MonitoredItemCreateRequest:
        data, pos, end = buffer._data, buffer._cur_pos, buffer._cur_pos + buffer._size
        if pos + 3 + tail_size > end:
            return generic(buffer)
        kind = data[pos]
        if kind == 3:
            namespace, length = string_id(data, pos + 1)
            start = pos + 7
            pos = start + length
            if length < 0 or pos + tail_size > end:
                return generic(buffer)
            # (a str identifier: NodeId finds the String type itself, cheaper than checking the one given)
            nid = node_id(bytes(data[start:pos]).decode(get_string_encoding(), errors="surrogateescape"), namespace)
        elif kind == 2:
            if pos + 7 + tail_size > end:
                return generic(buffer)
            namespace, identifier = numeric_id(data, pos + 1)
            nid, pos = node_id(identifier, namespace, _NUMERIC), pos + 7
        elif kind == 1:
            namespace, identifier = four_byte_id(data, pos + 1)
            nid, pos = node_id(identifier, namespace, _FOUR_BYTE), pos + 4
        elif kind == 0:
            nid, pos = node_id(data[pos + 1], 0, _TWO_BYTE), pos + 2
        else:  # a GUID, a ByteString, an expanded NodeId: asyncua's
            return generic(buffer)
        (attribute, index_range, encoding_ns, encoding_name, mode, handle, interval, filter_kind, filter_id,
         filter_body, queue_size, discard) = tail(data, pos)
        mode_member = modes.get(mode)
        if (index_range != -1 or encoding_ns or encoding_name != -1 or filter_kind or filter_id or filter_body
                or mode_member is None):
            return generic(buffer)
        pos += tail_size
        buffer._cur_pos, buffer._size = pos, end - pos
        return item(ItemToMonitor=read_value_id(NodeId=nid, AttributeId=attribute, IndexRange=None,
                                                DataEncoding=qualified_name(None, 0)),
                    MonitoringMode=mode_member,
                    RequestedParameters=parameters(ClientHandle=handle, SamplingInterval=interval,
                                                   Filter=extension(), QueueSize=queue_size,
                                                   DiscardOldest=bool(discard)))

    return decode
