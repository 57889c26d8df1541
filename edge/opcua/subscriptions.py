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
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

from asyncua import ua
from asyncua.server.internal_subscription import InternalSubscription
from asyncua.server.monitored_item_service import MonitoredItemService
from asyncua.server.subscription_service import SubscriptionService

from edge.opcua.encoding import data_change_of_notes, data_value_bytes, handle_prefix
from edge.opcua.values import SharedDataValue, same_reading

_DISABLED = ua.MonitoringMode.Disabled


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
        queue = subscription._triggered_datachanges
        pending = queue.get(mid)
        if pending is None:
            queue[mid] = [note]
            return True
        if item.queue_size and len(pending) >= item.queue_size:
            del pending[0]  # asyncua's choice whatever DiscardOldest says: the oldest goes
        pending.append(note)
        return True

    def _delete_monitored_items(self, mid: int) -> ua.StatusCode:
        item = self._monitored_items.get(mid)
        if item is not None:
            self._resolved.pop(item.callback_handle, None)
        return super()._delete_monitored_items(mid)

    async def datachange_callback(self, handle: int, value: ua.DataValue, error: ua.StatusCode | None = None) -> None:
        if error is None:
            if not isinstance(value, SharedDataValue):
                value = copy.deepcopy(value)  # someone else's value: keep a private copy, as asyncua does
            if self.notify(handle, value):
                return
        await super().datachange_callback(handle, value, error)


class GatewaySubscription(InternalSubscription):
    """asyncua's subscription, publishing its data changes as one pre-encoded notification."""

    def _pop_triggered_datachanges(self, result: ua.PublishResult) -> None:
        queued: dict[int, list[Any]] = self._triggered_datachanges
        if not queued:
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
        result = await super().create_subscription(params, callback, session_id, request_callback)
        subscription = self.subscriptions[result.SubscriptionId]
        subscription.__class__ = GatewaySubscription
        subscription.monitored_item_srv = GatewayMonitoredItems(subscription, self.aspace)
        return result


def install(service: SubscriptionService) -> None:
    """Make `service` (the server's, before any client subscribes) create GatewaySubscriptions."""
    service.__class__ = GatewaySubscriptions


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
