"""Client sessions serving Browse, TranslateBrowsePaths, Read and DeleteMonitoredItems requests of many operations
in slices.

asyncua answers such a request in one go: the node client of the OPC UA benchmark browses the gateway's tree
500 folders per request, which held the daemon's loop 30-60 ms just to decode the request and as much again
to browse (edge.opcua.views made the browse itself cheap). `GatewaySession` decodes and answers the
operations a few at a time (edge.opcua.turns) with the loop given a turn whenever a slice has held it long
enough; each operation is answered on its own, as asyncua answers it, so the results are the same, in the
same order. edge.opcua.pending_items leaves the operations encoded until a slice takes them, and
edge.opcua.large_responses encodes the answer in slices too.
"""

from __future__ import annotations

from typing import Any

from asyncua import ua
from asyncua.common.callback import CallbackType, ServerItemCallback
from asyncua.crypto.permission_rules import User
from asyncua.server.internal_session import InternalSession

from edge.opcua.subscriptions import GatewayMonitoredItems
from edge.opcua.turns import slices
from edge.opcua.views import Subtypes


class GatewaySession(InternalSession):
    """asyncua's session, serving a request's operations a slice at a time (no state of its own)."""

    async def browse(self, params: ua.BrowseParameters) -> list[ua.BrowseResult]:
        results: list[ua.BrowseResult] = []
        subtypes: Subtypes = {}
        async for chunk in slices(params.NodesToBrowse):
            results += self.iserver.view_service.browse(ua.BrowseParameters(
                View=params.View, RequestedMaxReferencesPerNode=params.RequestedMaxReferencesPerNode,
                NodesToBrowse=chunk), subtypes)
        return results

    async def translate_browsepaths_to_nodeids(self, params: list[ua.BrowsePath]) -> list[ua.BrowsePathResult]:
        results: list[ua.BrowsePathResult] = []
        subtypes: Subtypes = {}
        async for chunk in slices(params):
            results += self.iserver.view_service.translate_browsepaths_to_nodeids(chunk, subtypes)
        return results

    async def read(self, params: ua.ReadParameters) -> list[ua.DataValue]:
        """asyncua's: the PreRead and PostRead callbacks are told of the whole request, once."""
        user = self.user if self.user is not None else User()
        callbacks = self.iserver.callback_service
        await callbacks.dispatch(CallbackType.PreRead, ServerItemCallback(params, None, user, self.external))
        results: list[ua.DataValue] = []
        async for chunk in slices(params.NodesToRead):
            results += self.iserver.attribute_service.read(ua.ReadParameters(
                MaxAge=params.MaxAge, TimestampsToReturn=params.TimestampsToReturn, NodesToRead=chunk))
        await callbacks.dispatch(CallbackType.PostRead, ServerItemCallback(params, results, user, self.external))
        return results

    async def delete_monitored_items(self, params: ua.DeleteMonitoredItemsParameters) -> list[ua.StatusCode]:
        """asyncua's, the items deleted a slice at a time (edge.opcua.subscriptions) with the loop given turns;
        the ItemSubscriptionDeleted callbacks told once, of the whole request, as asyncua tells them."""
        subscription = self.subscription_service.subscriptions.get(params.SubscriptionId)
        items = getattr(subscription, "monitored_item_srv", None)
        if not isinstance(items, GatewayMonitoredItems):  # (no such subscription: asyncua's refusal)
            return await super().delete_monitored_items(params)
        results = await items.delete_in_slices(params.MonitoredItemIds)
        await self.iserver.callback_service.dispatch(CallbackType.ItemSubscriptionDeleted, ServerItemCallback(
            params, results, None, self.external))
        return results


def adopt(session: Any) -> None:
    """Make one of asyncua's sessions a GatewaySession."""
    if type(session) is InternalSession:
        session.__class__ = GatewaySession
