"""A CreateMonitoredItems request decoded chunk by chunk gives asyncua's own items."""

from __future__ import annotations

import struct

from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import struct_from_binary, struct_to_binary

from edge.opcua import pending_items


def _request(count: int) -> ua.CreateMonitoredItemsParameters:
    items = []
    for index in range(count):
        item = ua.MonitoredItemCreateRequest()
        item.ItemToMonitor = ua.ReadValueId(NodeId=ua.NodeId(f"m{index}/Metrics/Macro/{index}", 2),
                                            AttributeId=ua.AttributeIds.Value)
        item.MonitoringMode = ua.MonitoringMode.Sampling if index % 3 else ua.MonitoringMode.Reporting
        filter_ = ua.DataChangeFilter(DeadbandType=ua.DeadbandType.Absolute, DeadbandValue=0.5) if index == 4 else None
        item.RequestedParameters = ua.MonitoringParameters(ClientHandle=index * 7, QueueSize=index, Filter=filter_,
                                                           SamplingInterval=100.0)
        items.append(item)
    return ua.CreateMonitoredItemsParameters(SubscriptionId=42, TimestampsToReturn=ua.TimestampsToReturn.Both,
                                             ItemsToCreate=items)


def _asyncuas(items: list[ua.MonitoredItemCreateRequest]) -> list[ua.MonitoredItemCreateRequest]:
    """The items as asyncua decodes each (a null filter comes back as an empty ExtensionObject)."""
    return [struct_from_binary(ua.MonitoredItemCreateRequest, Buffer(struct_to_binary(item))) for item in items]


def test_the_items_decode_in_chunks_as_asyncua_decodes_them() -> None:
    pending_items.install()
    pending_items.install()  # once per process, however often asked
    sent = _request(9)
    encoded = struct_to_binary(sent)
    got = struct_from_binary(ua.CreateMonitoredItemsParameters, Buffer(encoded))
    items = got.ItemsToCreate
    assert isinstance(items, pending_items.PendingItems)
    assert (got.SubscriptionId, got.TimestampsToReturn, len(items)) == (42, ua.TimestampsToReturn.Both, 9)
    theirs = _asyncuas(sent.ItemsToCreate)
    assert items.take(4) == theirs[:4]
    assert items.take(4) == theirs[4:8]
    assert list(items) == theirs  # the rest decoded at a plain read
    assert items.take(4) == []
    got.ItemsToCreate = list(items)
    assert struct_to_binary(got) == encoded


def test_a_null_or_empty_item_array_is_no_item_and_other_types_decode_as_before() -> None:
    pending_items.install()
    empty = struct_from_binary(ua.CreateMonitoredItemsParameters, Buffer(struct_to_binary(_request(0))))
    assert list(empty.ItemsToCreate) == []
    null = struct.pack("<Iii", 1, ua.TimestampsToReturn.Source, -1)  # subscription, timestamps, null array
    assert len(struct_from_binary(ua.CreateMonitoredItemsParameters, Buffer(null)).ItemsToCreate) == 0
    modify = ua.ModifyMonitoredItemsParameters(SubscriptionId=3, ItemsToModify=[ua.MonitoredItemModifyRequest()])
    assert struct_from_binary(ua.ModifyMonitoredItemsParameters, Buffer(struct_to_binary(modify))) == modify


def test_browse_read_and_translate_requests_decode_on_demand_as_asyncua_decodes_them() -> None:
    pending_items.install()
    nodes = [ua.NodeId(f"m{index}/Metrics", 2) for index in range(7)]
    browse = ua.BrowseParameters(RequestedMaxReferencesPerNode=5, NodesToBrowse=[ua.BrowseDescription(
        NodeId=node, ReferenceTypeId=ua.NodeId(ua.ObjectIds.HierarchicalReferences), ResultMask=63)
        for node in nodes])
    read = ua.ReadParameters(MaxAge=250.0, TimestampsToReturn=ua.TimestampsToReturn.Source,
                             NodesToRead=[ua.ReadValueId(NodeId=node, AttributeId=ua.AttributeIds.Value)
                                          for node in nodes])
    translate = ua.TranslateBrowsePathsToNodeIdsParameters(BrowsePaths=[ua.BrowsePath(
        StartingNode=node, RelativePath=ua.RelativePath(Elements=[ua.RelativePathElement(
            TargetName=ua.QualifiedName("Axis", 2))])) for node in nodes])
    for sent, field in ((browse, "NodesToBrowse"), (read, "NodesToRead"), (translate, "BrowsePaths")):
        encoded = struct_to_binary(sent)
        got = struct_from_binary(type(sent), Buffer(encoded))
        pending = getattr(got, field)
        assert isinstance(pending, pending_items.PendingItems)
        assert pending.take(3) == getattr(sent, field)[:3]  # the first slice, the rest still encoded
        assert list(pending) == getattr(sent, field)
        setattr(got, field, list(pending))
        assert got == sent
        assert struct_to_binary(got) == encoded
