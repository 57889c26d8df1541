"""A client's subscription to the gateway's values, in process (asyncua's server objects, no network): what
each publish carries, decoded from its bytes as a client would."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import pytest
import pytest_asyncio
from asyncua import Server, ua
from asyncua.ua.ua_binary import struct_from_binary, struct_to_binary

from edge.opcua import subscriptions
from edge.opcua.address_space import GatewaySpace
from edge.samples import MetricSpec, MetricType, Quality, Sample

pytestmark = pytest.mark.asyncio(loop_scope="module")  # one asyncua server (5 s to build) for the module
CNC_MS = 1_764_072_000_000
_MACHINES = itertools.count()
SPECS = [MetricSpec(f"Macro/{n}", MetricType.DOUBLE) for n in range(4)]


class _Request:
    def __init__(self) -> None:
        self.results: list[ua.StatusCode] = []


@dataclass
class Subscribed:
    space: GatewaySpace
    machine: str
    subscription: Any
    published: list[Any] = field(default_factory=list)  # decoded DataChangeNotifications (client side)

    async def publish(self) -> list[tuple[int, object, int]]:
        """(client handle, value, status code) of every notification of one publish, in order."""
        self.published.clear()
        await self.subscription.publish_results()
        return [(item.ClientHandle, item.Value.Value.Value, item.Value.StatusCode.value)
                for notification in self.published for item in notification.MonitoredItems]

    async def monitor(self, metric: str, handle: int, queue_size: int, filter_: Any = None) -> int:
        item = ua.MonitoredItemCreateRequest()
        item.ItemToMonitor = ua.ReadValueId(NodeId=ua.NodeId(f"{self.machine}/Metrics/{metric}", self.space.ns),
                                            AttributeId=ua.AttributeIds.Value)
        item.MonitoringMode = ua.MonitoringMode.Reporting
        item.RequestedParameters = ua.MonitoringParameters(ClientHandle=handle, QueueSize=queue_size)
        if filter_ is not None:
            item.RequestedParameters.Filter = filter_
        params = ua.CreateMonitoredItemsParameters(ItemsToCreate=[item])
        [result] = await self.subscription.monitored_item_srv.create_monitored_items(params)
        assert result.StatusCode.is_good()
        return int(result.MonitoredItemId)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def server() -> AsyncIterator[tuple[Server, GatewaySpace]]:
    server = Server()
    await server.init()
    subscriptions.install(server.iserver.subscription_service)
    space = GatewaySpace(server.iserver, await server.register_namespace("urn:test"))
    space.setup()
    yield server, space


@pytest_asyncio.fixture(loop_scope="module")
async def subscribed(server: tuple[Server, GatewaySpace]) -> AsyncIterator[Subscribed]:
    iserver, space = server[0].iserver, server[1]
    machine = f"m{next(_MACHINES)}"
    space.machine_online(machine, SPECS, [], lambda _spec: False)
    await space.update(machine, [Sample(spec.name, 0.0, spec.type, CNC_MS) for spec in SPECS])
    published: list[Any] = []

    async def forward(result: ua.PublishResult, _request: _Request) -> None:
        response = ua.PublishResponse(Parameters=result)
        decoded = struct_from_binary(ua.PublishResponse, ua.utils.Buffer(struct_to_binary(response)))
        published.extend(decoded.Parameters.NotificationMessage.NotificationData)

    params = ua.CreateSubscriptionParameters(RequestedPublishingInterval=3_600_000, RequestedLifetimeCount=10_000,
                                             RequestedMaxKeepAliveCount=1_000, PublishingEnabled=True)
    created = await iserver.subscription_service.create_subscription(params, forward, ua.NodeId(1, 0),
                                                                    request_callback=lambda _id: _Request())
    subscription = iserver.subscription_service.subscriptions[created.SubscriptionId]
    assert isinstance(subscription, subscriptions.GatewaySubscription)
    result = Subscribed(space, machine, subscription, published)
    try:
        yield result
    finally:
        await subscription.stop()


def _values(metric: str, *values: float, ms: int = CNC_MS) -> list[list[Sample]]:
    return [[Sample(metric, value, MetricType.DOUBLE, ms + index)] for index, value in enumerate(values)]


async def _feed(subscribed: Subscribed, batches: list[list[Sample]]) -> None:
    for batch in batches:
        await subscribed.space.update(subscribed.machine, batch)


def _give_deadband(subscribed: Subscribed, mid: int, handle: int, deadband: float) -> None:
    """ModifyMonitoredItems: the item gets an absolute deadband (and so leaves its tap for asyncua's path)."""
    flt = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValue, DeadbandType=ua.DeadbandType.Absolute,
                              DeadbandValue=deadband)
    modify = ua.MonitoredItemModifyRequest(MonitoredItemId=mid, RequestedParameters=ua.MonitoringParameters(
        ClientHandle=handle, QueueSize=10, Filter=flt))
    subscribed.subscription.monitored_item_srv.modify_monitored_items(
        ua.ModifyMonitoredItemsParameters(ItemsToModify=[modify]))


async def test_each_item_keeps_its_queue_size_of_latest_values(subscribed: Subscribed) -> None:
    await subscribed.monitor("Macro/0", 10, queue_size=1)
    await subscribed.monitor("Macro/1", 11, queue_size=3)
    assert await subscribed.publish() == [(10, 0.0, 0), (11, 0.0, 0)]  # the current values first
    await _feed(subscribed, _values("Macro/0", 1, 2, 3) + _values("Macro/1", 1, 2, 3, 4, 5))
    assert await subscribed.publish() == [(10, 3.0, 0), (11, 3.0, 0), (11, 4.0, 0), (11, 5.0, 0)]
    assert await subscribed.publish() == []


async def test_an_unchanged_value_is_not_sent_again_but_a_status_change_is(subscribed: Subscribed) -> None:
    await subscribed.monitor("Macro/2", 7, queue_size=5)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/2", 0.0, ms=CNC_MS + 500))  # only the CNC time moved
    assert await subscribed.publish() == []
    stale = Sample("Macro/2", 0.0, MetricType.DOUBLE, CNC_MS + 600, Quality.STALE)
    await subscribed.space.update(subscribed.machine, [stale])
    await subscribed.space.offline(subscribed.machine)
    assert await subscribed.publish() == [(7, 0.0, ua.StatusCodes.UncertainLastUsableValue),
                                          (7, None, ua.StatusCodes.BadNoCommunication)]


async def test_a_filtered_item_follows_asyncuas_path(subscribed: Subscribed) -> None:
    flt = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValueTimestamp)
    await subscribed.monitor("Macro/3", 3, queue_size=10, filter_=flt)
    await subscribed.monitor("Macro/0", 4, queue_size=10)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/3", 0.0, ms=CNC_MS + 500) + _values("Macro/0", 0.0, 9.5))
    assert await subscribed.publish() == [(3, 0.0, 0), (4, 9.5, 0)]  # the timestamp trigger sees the new time


async def test_a_disabled_item_hears_nothing_until_enabled(subscribed: Subscribed) -> None:
    item = await subscribed.monitor("Macro/1", 5, queue_size=1)
    await subscribed.publish()
    service = subscribed.subscription.monitored_item_srv
    await service.set_monitoring_mode(ua.MonitoringMode.Disabled, [item])
    await _feed(subscribed, _values("Macro/1", 1, 2))
    assert await subscribed.publish() == []
    await service.set_monitoring_mode(ua.MonitoringMode.Reporting, [item])
    assert await subscribed.publish() == [(5, 2.0, 0)]


async def test_a_deleted_item_and_unmonitored_nodes_queue_nothing(subscribed: Subscribed) -> None:
    item = await subscribed.monitor("Macro/1", 5, queue_size=1)
    await subscribed.publish()
    subscribed.subscription.monitored_item_srv.delete_monitored_items([item])
    await _feed(subscribed, _values("Macro/1", 1) + _values("Macro/2", 1))
    assert subscribed.subscription._triggered_datachanges == {}
    assert await subscribed.publish() == []


async def test_machines_share_equal_static_attributes_and_change_them_apart(subscribed: Subscribed) -> None:
    space, first = subscribed.space, subscribed.machine
    second = f"m{next(_MACHINES)}"
    space.machine_online(second, SPECS, [], lambda _spec: False)
    aspace = space.iserver.aspace

    def attribute(machine: str, attribute_id: ua.AttributeIds) -> Any:
        return aspace[ua.NodeId(f"{machine}/Metrics/Macro/1", space.ns)].attributes[attribute_id]

    for attribute_id in (ua.AttributeIds.DataType, ua.AttributeIds.AccessLevel, ua.AttributeIds.DisplayName):
        assert attribute(first, attribute_id).value is attribute(second, attribute_id).value
    assert attribute(first, ua.AttributeIds.NodeId).value.Value.Value.Identifier == f"{first}/Metrics/Macro/1"
    assert attribute(second, ua.AttributeIds.NodeId).value.Value.Value.Identifier == f"{second}/Metrics/Macro/1"
    space.machine_online(second, SPECS, [], lambda spec: spec.name == "Macro/1")  # now writable there only
    assert attribute(second, ua.AttributeIds.AccessLevel).value.Value.Value & ua.AccessLevel.CurrentWrite.mask
    assert not attribute(first, ua.AttributeIds.AccessLevel).value.Value.Value & ua.AccessLevel.CurrentWrite.mask


async def test_a_deleted_item_gets_nothing_and_is_forgotten(subscribed: Subscribed) -> None:
    mid = await subscribed.monitor("Macro/1", 21, queue_size=5)
    await subscribed.monitor("Macro/2", 22, queue_size=5)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/1", 1.0) + _values("Macro/2", 1.0))
    assert await subscribed.publish() == [(21, 1.0, 0), (22, 1.0, 0)]
    items = subscribed.subscription.monitored_item_srv
    items.delete_monitored_items([mid])
    await _feed(subscribed, _values("Macro/1", 2.0) + _values("Macro/2", 2.0))
    assert await subscribed.publish() == [(22, 2.0, 0)]
    assert [resolved[0] for resolved in items._resolved.values()] == [mid + 1]


async def test_a_value_nobody_monitors_is_read_as_its_last_sample_shows_it(subscribed: Subscribed) -> None:
    space, machine = subscribed.space, subscribed.machine
    node = ua.NodeId(f"{machine}/Metrics/Macro/3", space.ns)
    before = datetime.now(UTC)
    await _feed(subscribed, _values("Macro/3", 1.5, 2.5, ms=CNC_MS + 100))
    after = datetime.now(UTC)
    value = space.iserver.aspace.read_attribute_value(node, ua.AttributeIds.Value)
    assert (value.Value.Value, value.Value.VariantType, value.StatusCode.value) == (2.5, ua.VariantType.Double, 0)
    assert value.SourceTimestamp == datetime.fromtimestamp((CNC_MS + 101) / 1000, UTC)
    assert before <= value.ServerTimestamp <= after
    assert struct_to_binary(value) == value.encoded  # what a Read sends is what a subscription would
    assert space.iserver.aspace.read_attribute_value(node, ua.AttributeIds.Value) is value  # built once
    await subscribed.space.offline(machine)
    offline = space.iserver.aspace.read_attribute_value(node, ua.AttributeIds.Value)
    assert (offline.Value.Value, offline.StatusCode.value) == (None, ua.StatusCodes.BadNoCommunication)


async def test_an_item_given_a_deadband_later_leaves_the_short_path(subscribed: Subscribed) -> None:
    mid = await subscribed.monitor("Macro/2", 31, queue_size=10)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/2", 1.0, 2.0))
    assert await subscribed.publish() == [(31, 1.0, 0), (31, 2.0, 0)]
    _give_deadband(subscribed, mid, 31, 5.0)
    await _feed(subscribed, _values("Macro/2", 3.0, 10.0, 12.0))  # deltas 1, 7, 2 from the value before
    assert await subscribed.publish() == [(31, 10.0, 0)]


async def test_a_change_queued_by_its_tap_then_one_by_asyncuas_path_both_arrive_in_order(
        subscribed: Subscribed) -> None:
    mid = await subscribed.monitor("Macro/1", 61, queue_size=10)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/1", 1.0))  # queued by the tap (bare, not in a list)
    _give_deadband(subscribed, mid, 61, 5.0)
    await _feed(subscribed, _values("Macro/1", 9.0, ms=CNC_MS + 10))  # asyncua's path, into the same queue
    assert await subscribed.publish() == [(61, 1.0, 0), (61, 9.0, 0)]


async def test_a_modified_queue_size_bounds_the_next_changes(subscribed: Subscribed) -> None:
    mid = await subscribed.monitor("Macro/3", 41, queue_size=1)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/3", 1.0, 2.0))
    assert await subscribed.publish() == [(41, 2.0, 0)]
    modify = ua.MonitoredItemModifyRequest(MonitoredItemId=mid, RequestedParameters=ua.MonitoringParameters(
        ClientHandle=41, QueueSize=3))
    subscribed.subscription.monitored_item_srv.modify_monitored_items(
        ua.ModifyMonitoredItemsParameters(ItemsToModify=[modify]))
    await _feed(subscribed, _values("Macro/3", 3.0, 4.0, 5.0, 6.0))
    assert await subscribed.publish() == [(41, 4.0, 0), (41, 5.0, 0), (41, 6.0, 0)]


async def test_two_items_on_one_node_and_one_created_later_each_get_every_change(subscribed: Subscribed) -> None:
    await subscribed.monitor("Macro/0", 51, queue_size=5)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/0", 1.0))
    await subscribed.monitor("Macro/0", 52, queue_size=5)  # its first value: the current one
    await _feed(subscribed, _values("Macro/0", 2.0) + _values("Macro/0", 2.0, ms=CNC_MS + 50))
    assert await subscribed.publish() == [(51, 1.0, 0), (51, 2.0, 0), (52, 1.0, 0), (52, 2.0, 0)]


async def test_a_client_asking_a_faster_publishing_interval_gets_the_servers_minimum(
        server: tuple[Server, GatewaySpace]) -> None:
    service = server[0].iserver.subscription_service
    fastest = subscriptions.MIN_PUBLISHING_INTERVAL_MS
    for asked, revised in ((0.0, fastest), (5.0, fastest), (250.0, 250.0)):
        params = ua.CreateSubscriptionParameters(RequestedPublishingInterval=asked, RequestedLifetimeCount=100,
                                                 RequestedMaxKeepAliveCount=10, PublishingEnabled=True)

        async def forward(_result: ua.PublishResult, _request: _Request) -> None:
            return None

        created = await service.create_subscription(params, forward, ua.NodeId(1, 0),
                                                    request_callback=lambda _id: None)
        assert created.RevisedPublishingInterval == revised
        await service.delete_subscriptions([created.SubscriptionId])


async def test_a_large_create_gives_the_loop_turns_and_holds_its_changes_until_it_answers(
        subscribed: Subscribed) -> None:
    await subscribed.publish()
    count = 2 * subscriptions.CREATE_CHUNK + 10
    items = []
    for handle in range(count):
        item = ua.MonitoredItemCreateRequest()
        item.ItemToMonitor = ua.ReadValueId(NodeId=ua.NodeId(f"{subscribed.machine}/Metrics/Macro/{handle % 4}",
                                                             subscribed.space.ns), AttributeId=ua.AttributeIds.Value)
        item.MonitoringMode = ua.MonitoringMode.Reporting
        item.RequestedParameters = ua.MonitoringParameters(ClientHandle=1000 + handle, QueueSize=5)
        items.append(item)
    create = asyncio.ensure_future(subscribed.subscription.monitored_item_srv.create_monitored_items(
        ua.CreateMonitoredItemsParameters(ItemsToCreate=items)))
    turns = 0
    while not create.done():  # each turn of this loop is one the create gave the loop back
        turns += 1
        if turns == 2:  # created in part: a publish now carries none of their values, nor a new one
            await _feed(subscribed, _values("Macro/1", 7.0))
            assert await subscribed.publish() == []
        await asyncio.sleep(0)
    results = create.result()
    assert turns >= 2
    assert [result.StatusCode.is_good() for result in results] == [True] * count
    # held back until the answer: each item's first value, and 7.0 for those of Macro/1 made before it came
    chunk = subscriptions.CREATE_CHUNK
    expected = [(1000 + h, 7.0 if h % 4 == 1 and h >= chunk else 0.0) for h in range(count)]
    expected += [(1000 + h, 7.0) for h in range(chunk) if h % 4 == 1]
    assert sorted((handle, value) for handle, value, _ in await subscribed.publish()) == sorted(expected)


async def test_a_tapped_item_off_and_on_again_compares_with_the_value_it_last_saw(subscribed: Subscribed) -> None:
    item = await subscribed.monitor("Macro/2", 61, queue_size=5)
    await subscribed.publish()
    await _feed(subscribed, _values("Macro/2", 5.0, 6.0))  # through the item's tap
    assert await subscribed.publish() == [(61, 5.0, 0), (61, 6.0, 0)]
    service = subscribed.subscription.monitored_item_srv
    await service.set_monitoring_mode(ua.MonitoringMode.Disabled, [item])
    await service.set_monitoring_mode(ua.MonitoringMode.Reporting, [item])
    assert await subscribed.publish() == []  # 6.0 again: nothing a client would see has changed
    await _feed(subscribed, _values("Macro/2", 6.0, ms=CNC_MS + 900) + _values("Macro/2", 7.0))
    assert await subscribed.publish() == [(61, 7.0, 0)]


async def test_a_machine_nobody_watches_keeps_its_values_and_its_first_item_hears_the_next(
        subscribed: Subscribed) -> None:
    space = subscribed.space
    second = Subscribed(space, f"m{next(_MACHINES)}", subscribed.subscription, subscribed.published)
    space.machine_online(second.machine, SPECS, [], lambda _spec: False)
    await subscribed.monitor("Macro/1", 61, queue_size=5)  # an item on the first machine only
    await subscribed.publish()
    await _feed(second, _values("Macro/1", 7.0))
    assert subscribed.subscription._triggered_datachanges == {}
    node = ua.NodeId(f"{second.machine}/Metrics/Macro/1", space.ns)
    assert space.iserver.aspace.read_attribute_value(node, ua.AttributeIds.Value).Value.Value == 7.0
    await second.monitor("Macro/1", 62, queue_size=5)
    assert await second.publish() == [(62, 7.0, 0)]  # its first value: the one stored while nobody watched
    await _feed(second, _values("Macro/1", 8.0) + _values("Macro/2", 8.0))
    await _feed(subscribed, _values("Macro/1", 9.0))
    assert await second.publish() == [(62, 8.0, 0), (61, 9.0, 0)]
