"""The usual monitored item decoded by edge.opcua.item_decoding is the item asyncua decodes; others go to asyncua."""

from __future__ import annotations

import uuid

import pytest
from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua import ua_binary
from asyncua.ua.ua_binary import struct_from_binary, struct_to_binary

from edge.opcua.item_decoding import fast_items


def _item(node: ua.NodeId, **changes: object) -> ua.MonitoredItemCreateRequest:
    item = ua.MonitoredItemCreateRequest(
        ItemToMonitor=ua.ReadValueId(NodeId=node, AttributeId=ua.AttributeIds.Value),
        MonitoringMode=ua.MonitoringMode.Reporting,
        RequestedParameters=ua.MonitoringParameters(ClientHandle=7, SamplingInterval=250.0, QueueSize=10))
    for name, value in changes.items():
        target = item.RequestedParameters if hasattr(item.RequestedParameters, name) else item.ItemToMonitor
        setattr(target if hasattr(target, name) else item, name, value)
    return item


ITEMS = [
    _item(ua.NodeId("m1/Metrics/Macro/500", 2)),
    _item(ua.NodeId("m1/Métriques/ß/ä", 3)),  # not ASCII
    _item(ua.NodeId("", 2)),
    _item(ua.NodeId(2258, 0)),  # numeric ids of each encoding size
    _item(ua.NodeId(70000, 5)),
    _item(ua.NodeId(300, 1)),
    _item(ua.NodeId(5, 0)),
    _item(ua.NodeId("x", 2), MonitoringMode=ua.MonitoringMode.Sampling, DiscardOldest=False, QueueSize=0,
          ClientHandle=0xFFFFFFFF, SamplingInterval=-1.0),
    _item(ua.NodeId("x", 2), MonitoringMode=ua.MonitoringMode.Disabled, AttributeId=ua.AttributeIds.EventNotifier),
    # shapes left to asyncua
    _item(ua.NodeId("x", 2), Filter=ua.DataChangeFilter(DeadbandType=ua.DeadbandType.Absolute, DeadbandValue=0.5)),
    _item(ua.NodeId("x", 2), IndexRange="1:2"),
    _item(ua.NodeId("x", 2), DataEncoding=ua.QualifiedName("Default Binary")),
    _item(ua.NodeId(uuid.UUID(int=7), 2)),
    _item(ua.NodeId(b"\x01\x02", 2)),
    _item(ua.ExpandedNodeId("x", 2, ua.NodeIdType.String, "urn:other", 0)),
]


@pytest.mark.parametrize("sent", ITEMS, ids=range(len(ITEMS)))
def test_an_item_decodes_as_asyncua_decodes_it(sent: ua.MonitoredItemCreateRequest) -> None:
    encoded = struct_to_binary(sent) + b"\xAB\xCD"  # what follows must be left where it is
    generic = ua_binary._create_dataclass_deserializer(ua.MonitoredItemCreateRequest)
    expected = struct_from_binary(ua.MonitoredItemCreateRequest, Buffer(encoded))
    buffer = Buffer(encoded)
    got = fast_items(generic)(buffer)
    assert got == expected
    assert type(got.MonitoringMode) is type(expected.MonitoringMode)
    assert type(got.RequestedParameters.Filter) is type(expected.RequestedParameters.Filter)
    assert bytes(buffer) == b"\xAB\xCD"


def test_a_run_of_items_and_a_short_buffer() -> None:
    generic = ua_binary._create_dataclass_deserializer(ua.MonitoredItemCreateRequest)
    decode = fast_items(generic)
    buffer = Buffer(b"".join(struct_to_binary(item) for item in ITEMS))
    assert [decode(buffer) for _ in ITEMS] == [struct_from_binary(ua.MonitoredItemCreateRequest,
                                                                  Buffer(struct_to_binary(i))) for i in ITEMS]
    assert len(buffer) == 0
    cut = struct_to_binary(ITEMS[0])[:-1]  # one byte short: asyncua's error, not a wrong item
    with pytest.raises(Exception) as fast_error:
        decode(Buffer(cut))
    with pytest.raises(Exception) as asyncua_error:
        generic(Buffer(cut))
    assert type(fast_error.value) is type(asyncua_error.value)
    buffer = Buffer(struct_to_binary(ITEMS[0]) + b"\x00" * 8, size=len(struct_to_binary(ITEMS[0])) - 1)
    with pytest.raises(Exception) as bounded_error:  # a buffer shorter than its bytes: its own size counts
        decode(buffer)
    assert type(bounded_error.value) is type(asyncua_error.value)
