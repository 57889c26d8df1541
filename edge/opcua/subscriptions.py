"""Clients' subscriptions, with a short path for the gateway's own value changes.

asyncua handles each value change of each monitored item in a coroutine that builds a
MonitoredItemNotification (and a default DataValue it throws away), deep-copies the value, compares it with
the previous one, and queues it; at publishing time every notification is encoded field by field. With a
client subscribed to every metric that was most of the gateway's CPU (docs/opcua.md). Here:

- `GatewayMonitoredItems.notify` takes a change synchronously: the same checks asyncua makes (item disabled,
  value and status unchanged since the last one), the same queue (the item's revised queue size, oldest
  dropped first: with queue size 1 only the latest value within a publishing interval is sent), and the
  change is queued as (client handle, DataValue) only. Items with a filter (deadband, another trigger) and
  subscriptions without a publishing interval keep asyncua's path, which stays correct for them.
- `GatewaySubscription` publishes the queued changes as one pre-encoded DataChangeNotification
  (edge.opcua.encoding): the same bytes asyncua writes, from values encoded once when they were built.

asyncua builds the subscription objects itself, with no factory to hand it a subclass; the subscription
subclass adds methods and no state, so `install` switches the class of the service and of each new
subscription, and gives it a GatewayMonitoredItems (a subscription has no monitored item yet then).

- `taps_of` goes further for the usual item (a client's, enabled, no filter, a publishing interval): it
  resolves what `notify` looks up and checks on every change (the item, its client handle's bytes, its queue
  bound, its subscription) once, into a tap the address space keeps per metric and queues to inline. The
  taps are made again whenever `CHANGES` moves: a data-change callback added or removed (the address space's
  class is switched by `install` too), an item's monitoring mode or parameters changed.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
from collections.abc import Callable, Sequence
from typing import Any

from asyncua import ua
from asyncua.server.address_space import AddressSpace
from asyncua.server.internal_subscription import InternalSubscription
from asyncua.server.monitored_item_service import MonitoredItemService, MonitoredItemValues
from asyncua.server.subscription_service import SubscriptionService

from edge.opcua import pending_items
from edge.opcua.encoding import data_change_of_notes, data_value_bytes, handle_prefix
from edge.opcua.pending_items import PendingItems
from edge.opcua.turns import slices
from edge.opcua.values import SharedDataValue, same_reading

_DISABLED = ua.MonitoringMode.Disabled
# Bumped whenever which monitored items a value change reaches, or how, may have changed (a data-change
# callback added or removed, an item's mode or parameters modified): the address space makes a metric's
# taps again when it sees a count other than the one they were made at.
CHANGES = [0]
# The server's fastest publishing interval: a client's subscription asking less (0 included: asyncua would
# send a Publish response per change) gets this, as OPC 10000-4 5.13.2 lets a server revise it. 20 ms keeps a
# change's wait for its publish short; 50 and 100 ms cost that latency without a CPU saving the fleet
# benchmark could tell apart (docs/opcua.md).
MIN_PUBLISHING_INTERVAL_MS = 20.0
_UNBOUNDED = 1 << 62  # a queue bound no queue reaches (asyncua's queue size 0: no limit)
# CreateMonitoredItems is served this many items at a time, the daemon's loop given a turn between two
# chunks: asyncua creates a request's items in one go (10,000 items held the loop about half a second,
# poll overruns and MQTT delays with it). ~25 us an item: a chunk holds the loop about 5 ms.
CREATE_CHUNK = 200

# (the item's values, monitored item id, encoded client handle, queue bound, its subscription): what a
# change needs to be queued as a notification of a client's item (edge.opcua.address_space, inlined)
Tap = tuple[Any, int, bytes, int, InternalSubscription]


def _changed() -> None:
    CHANGES[0] += 1


class TappedValues(MonitoredItemValues):
    """A tapped item's values (`link`): its current value is its metric's, read from the metric's slot (`read()`),
    since every change of the metric reaches the item while it is tapped. A change then costs no store per item.

    Unlinked (`unlink`) when the slot's taps are made again, with the value the item last saw; asyncua's or
    `notify`'s store into it (the item off its tap before the slot noticed) unlinks it too."""

    slot: Any

    @property
    def current_dvalue(self) -> ua.DataValue | None:
        return self.slot.read()

    @current_dvalue.setter
    def current_dvalue(self, value: ua.DataValue | None) -> None:
        self.__class__ = MonitoredItemValues
        self.current_dvalue = value


def link(values: MonitoredItemValues, slot: Any) -> None:
    """Make a tapped item's current value its slot's (TappedValues)."""
    if type(values) is MonitoredItemValues:
        values.__class__ = TappedValues
    if type(values) is TappedValues:
        values.slot = slot


def unlink(values: MonitoredItemValues) -> None:
    """The item's current value held by the item again: the one it last saw, its slot's until now."""
    if type(values) is TappedValues:
        current = values.slot.read()
        values.__class__ = MonitoredItemValues
        values.current_dvalue = current


def enqueue(queue: dict[int, Any], mid: int, note: Any, bound: int) -> None:
    """Queue a notification for monitored item `mid` in its subscription's pending changes, at most `bound`
    of them (asyncua's choice whatever DiscardOldest says: the oldest goes).

    An item's first pending notification, when it is bytes (a client's, pre-encoded), is queued bare, not in a
    list: an item rarely has two within a publishing interval, and a list per notification was ~0.2 us of
    allocation, tracking and freeing. A second one makes it a list (`queue_more`)."""
    pending = queue.get(mid)
    if pending is None:
        queue[mid] = note if type(note) is bytes else [note]
    else:
        queue_more(queue, mid, pending, note, bound)


def queue_more(queue: dict[int, Any], mid: int, pending: Any, note: Any, bound: int) -> None:
    """Queue `note` behind `pending`, the item's notifications queued so far (a bare bytes or a list)."""
    if type(pending) is bytes:
        pending = queue[mid] = [pending]
    if len(pending) >= bound:
        del pending[0]
    pending.append(note)


class GatewayMonitoredItems(MonitoredItemService):
    """asyncua's monitored items of one subscription, with a synchronous path for a value change."""

    def __init__(self, isub: InternalSubscription, aspace: Any) -> None:
        super().__init__(isub, aspace)
        # callback handle -> (monitored item id, item), resolved on the item's first change: one lookup
        # per change instead of two. asyncua never reuses a handle, and a deleted item's callback is gone
        # from its attribute, so an entry is never stale when it is used; it is dropped with the item.
        self._resolved: dict[int, tuple[int, Any, bytes]] = {}  # + the item's encoded client handle

    def notify(self, handle: int, value: ua.DataValue) -> bool:
        """Queue the change for the item behind `handle`; False when the item needs asyncua's path.

        `value` must never be changed afterwards (it is kept, not copied)."""
        resolved = self._resolved.get(handle)
        if resolved is None:
            mid = self._monitored_datachange.get(handle)
            item = self._monitored_items.get(mid) if mid is not None else None
            if item is None:
                return True
            resolved = self._resolved[handle] = (mid, item, handle_prefix(item.client_handle))
        mid, item, prefix = resolved
        if item.mode == _DISABLED:
            return True
        subscription = self.isub
        if item.filter or subscription.data.RevisedPublishingInterval <= 0:  # a filter as asyncua reads it
            return False
        values = item.mvalue
        previous = values.current_dvalue
        values.current_dvalue = value  # (asyncua's own path moves current to old itself)
        if previous is not None and same_reading(previous, value):
            return True  # asyncua's default trigger (StatusValue): nothing a client sees has changed
        # a client's subscription queues the notification's bytes; the server's own ones read objects
        note: Any = prefix + data_value_bytes(value) if subscription.pub_request_callback is not None \
            else (item.client_handle, value)
        enqueue(subscription._triggered_datachanges, mid, note, item.queue_size or _UNBOUNDED)
        return True

    async def create_monitored_items(
            self, params: ua.CreateMonitoredItemsParameters) -> list[ua.MonitoredItemCreateResult]:
        """asyncua's, in chunks of CREATE_CHUNK items with the loop given a turn between two. The subscription
        holds back its data changes meanwhile (`GatewaySubscription.creating`): a client is sent no
        notification of an item before the response that tells it the item exists, as without chunks."""
        items = params.ItemsToCreate
        if len(items) <= CREATE_CHUNK:
            return await super().create_monitored_items(params)
        subscription: GatewaySubscription = self.isub
        results: list[ua.MonitoredItemCreateResult] = []
        subscription.creating += 1
        try:
            for start in range(0, len(items), CREATE_CHUNK):
                if start:
                    await asyncio.sleep(0)
                    if subscription.stopped:  # deleted meanwhile: what this call made goes too
                        await self.delete_all_in_slices()
                        return [ua.MonitoredItemCreateResult(
                            StatusCode=ua.StatusCode(ua.StatusCodes.BadSubscriptionIdInvalid)) for _ in items]
                try:  # a request still being decoded (edge.opcua.pending_items) decodes its next chunk
                    chunk = items.take(CREATE_CHUNK) if isinstance(items, PendingItems) \
                        else items[start:start + CREATE_CHUNK]
                except Exception:  # a malformed item: the request fails whole, as when asyncua decodes it
                    self.delete_monitored_items([r.MonitoredItemId for r in results if r.StatusCode.is_good()])
                    raise
                results += await super().create_monitored_items(ua.CreateMonitoredItemsParameters(
                    SubscriptionId=params.SubscriptionId, TimestampsToReturn=params.TimestampsToReturn,
                    ItemsToCreate=chunk))
        finally:
            subscription.creating -= 1
        return results

    def tap(self, handle: int) -> Tap | None:
        """The tap of the item behind `handle` when a change may be queued for it directly, without `notify`'s
        checks: a client's item, enabled, with no filter, in a subscription with a publishing interval. Valid
        until `CHANGES` moves (every change of what it resolves moves it)."""
        mid = self._monitored_datachange.get(handle)
        item = self._monitored_items.get(mid) if mid is not None else None
        subscription = self.isub
        if (item is None or item.mode == _DISABLED or item.filter or subscription.pub_request_callback is None
                or subscription.data.RevisedPublishingInterval <= 0):
            return None
        return item.mvalue, mid, handle_prefix(item.client_handle), item.queue_size or _UNBOUNDED, subscription

    def _delete_monitored_items(self, mid: int) -> ua.StatusCode:
        """asyncua's, without its walk of every data-change item to find the deleted one's callback (the item
        knows its callback's handle): deleting n items one by one walked n^2/2 entries. What the item had
        queued and not yet published goes with it: a client is sent nothing of an item it deleted."""
        item = self._monitored_items.get(mid)
        if item is not None:
            self._drop(mid, item)
        if item is None or self._monitored_events:  # (an event item: asyncua's own walk of its few)
            return super()._delete_monitored_items(mid)
        handle = item.callback_handle
        if handle is not None and self._monitored_datachange.get(handle) == mid:
            del self._monitored_datachange[handle]
            self.aspace.delete_datachange_callback(handle)
        del self._monitored_items[mid]
        return ua.StatusCode()

    def _drop(self, mid: int, item: Any) -> None:
        _changed()
        self._resolved.pop(item.callback_handle, None)
        self.isub._triggered_datachanges.pop(mid, None)
        self.isub._triggered_events.pop(mid, None)

    async def delete_in_slices(self, ids: Sequence[int]) -> list[ua.StatusCode]:
        """`delete_monitored_items(ids)` a slice at a time, the loop given turns between slices
        (edge.opcua.turns): 6,000 items at once held the daemon's loop ~85 ms on a slow host."""
        results: list[ua.StatusCode] = []
        async for chunk in slices(ids):
            results += self.delete_monitored_items(chunk)
        return results

    async def delete_all_in_slices(self) -> None:
        """Every item deleted, a slice at a time (items created meanwhile included)."""
        while self._monitored_items:
            await self.delete_in_slices(list(self._monitored_items))

    async def set_monitoring_mode(self, mode: ua.MonitoringMode, ids: list[int]) -> list[ua.StatusCode]:
        _changed()
        try:
            return await super().set_monitoring_mode(mode, ids)
        finally:
            _changed()

    def modify_monitored_items(self, params: ua.ModifyMonitoredItemsParameters) -> list[ua.MonitoredItemModifyResult]:
        try:
            return super().modify_monitored_items(params)
        finally:
            _changed()

    async def datachange_callback(self, handle: int, value: ua.DataValue, error: ua.StatusCode | None = None) -> None:
        if error is None:
            if not isinstance(value, SharedDataValue):
                value = copy.deepcopy(value)  # someone else's value: keep a private copy, as asyncua does
            if self.notify(handle, value):
                return
        await super().datachange_callback(handle, value, error)


class GatewaySubscription(InternalSubscription):
    """asyncua's subscription, publishing its data changes as one pre-encoded notification.

    Two attributes of its own, set when its class is switched: `creating`, the CreateMonitoredItems calls under
    way in chunks (its data changes are held back meanwhile: publishes are keep-alives), and `stopped`."""

    creating: int
    stopped: bool

    def has_published_results(self) -> bool:
        if self.creating and not self._startup:  # data changes held: a keep-alive when one is due
            self._keep_alive_count += 1
            return bool(self._keep_alive_count >= self.data.RevisedMaxKeepAliveCount)
        return super().has_published_results()

    async def stop(self) -> None:
        """asyncua's: its publishing loop ended, then its items deleted, here a slice at a time with the loop
        given turns (a client closing its session, or its connection dropping, deletes all of them)."""
        self.stopped = True
        task: asyncio.Task[None] | None = self._task  # type: ignore[has-type]  # (asyncua's, annotated there)
        self._task = None
        if task is not None:
            self._closing = True
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        items: GatewayMonitoredItems = self.monitored_item_srv
        await items.delete_all_in_slices()
        await super().stop()  # (its loop ended and no item left: nothing more to do)

    async def _enqueue_event(self, mid: int, eventdata: Any, size: int, queue: dict[int, Any]) -> None:
        pending = queue.get(mid)
        if type(pending) is bytes:  # a bare notification queued by a tap: asyncua's path expects a list
            queue[mid] = [pending]
        await super()._enqueue_event(mid, eventdata, size, queue)

    def _pop_triggered_datachanges(self, result: ua.PublishResult) -> None:
        queued: dict[int, list[Any]] = self._triggered_datachanges
        if not queued or self.creating:
            return
        notification: Any
        if self.pub_request_callback is None:  # one of the server's own: its callback reads the objects
            notification = ua.DataChangeNotification(MonitoredItems=[
                ua.MonitoredItemNotification(ClientHandle=handle, Value=value)
                for notes in queued.values() for handle, value in map(_pair, notes)])
        else:
            notification = data_change_of_notes(queued.values())
        queued.clear()
        result.NotificationMessage.NotificationData.append(notification)


def _pair(note: Any) -> tuple[int, ua.DataValue]:
    """(client handle, value) of a change queued for one of the server's own subscriptions: ours are pairs,
    asyncua's MonitoredItemNotifications."""
    if isinstance(note, tuple):
        return note
    return note.ClientHandle, note.Value


class GatewaySubscriptions(SubscriptionService):
    """asyncua's subscription service, whose new subscriptions are GatewaySubscriptions."""

    async def create_subscription(self, params: ua.CreateSubscriptionParameters, callback: Callable[..., Any],
                                  session_id: ua.NodeId,
                                  request_callback: Callable[..., Any] | None = None) -> ua.CreateSubscriptionResult:
        if request_callback is not None:  # a client's (the server's own are left as asked)
            params.RequestedPublishingInterval = max(params.RequestedPublishingInterval, MIN_PUBLISHING_INTERVAL_MS)
        result = await super().create_subscription(params, callback, session_id, request_callback)
        subscription = self.subscriptions[result.SubscriptionId]
        subscription.__class__ = GatewaySubscription
        subscription.creating = 0
        subscription.stopped = False
        subscription.monitored_item_srv = GatewayMonitoredItems(subscription, self.aspace)
        return result


class CountedCallbacks:
    """Mixed into the server's address space class: every data-change callback added or removed moves `CHANGES`."""

    def add_datachange_callback(self, nodeid: ua.NodeId, attr: ua.AttributeIds,
                                callback: Callable[..., Any]) -> tuple[ua.StatusCode, int]:
        _changed()
        return super().add_datachange_callback(nodeid, attr, callback)  # type: ignore[misc]

    def delete_datachange_callback(self, handle: int) -> None:
        _changed()
        super().delete_datachange_callback(handle)  # type: ignore[misc]


class GatewayAddressSpace(CountedCallbacks, AddressSpace):
    """asyncua's address space, counting its data-change callbacks' changes."""


def install(service: SubscriptionService) -> None:
    """Make `service` (the server's, before any client subscribes) create GatewaySubscriptions, and its address
    space count its data-change callbacks' changes (the address space keeps a metric's taps until they move);
    CreateMonitoredItems requests are decoded chunk by chunk as they are served (edge.opcua.pending_items)."""
    pending_items.install()
    service.__class__ = GatewaySubscriptions
    aspace = service.aspace
    kind = type(aspace)
    if not issubclass(kind, CountedCallbacks):
        aspace.__class__ = GatewayAddressSpace if kind is AddressSpace else type(
            f"Counted{kind.__name__}", (CountedCallbacks, kind), {})


def taps_of(callbacks: dict[int, Callable[..., Any]]) -> tuple[list[Tap], list[tuple[int, Callable[..., Any]]]]:
    """An attribute's data-change callbacks split: the taps of the items a change is queued for directly, and
    the (handle, callback) of the others (told through `notify`, or asyncua's coroutine)."""
    taps: list[Tap] = []
    others: list[tuple[int, Callable[..., Any]]] = []
    for handle, callback in callbacks.items():
        owner = getattr(callback, "__self__", None)
        tap = owner.tap(handle) if type(owner) is GatewayMonitoredItems else None
        if tap is None:
            others.append((handle, callback))
        else:
            taps.append(tap)
    return taps, others


_NONE: tuple[tuple[int, Any], ...] = ()


def notify_all(callbacks: dict[int, Callable[..., Any]],
               value: SharedDataValue) -> list[tuple[int, Any]] | tuple[tuple[int, Any], ...]:
    """Tell the monitored items behind `callbacks` (an attribute's data-change callbacks) of `value`;
    returns those that need asyncua's coroutine (to be awaited with (handle, value)), usually none."""
    slow: list[tuple[int, Any]] | None = None
    for handle, callback in callbacks.items():
        owner = getattr(callback, "__self__", None)
        if type(owner) is not GatewayMonitoredItems or not owner.notify(handle, value):
            if slow is None:
                slow = []
            slow.append((handle, callback))
    return _NONE if slow is None else slow
