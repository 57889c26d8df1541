"""A client's Publish request served without walking asyncua's chain of service comparisons.

asyncua's UaProcessor finds a request's service by comparing its type id with a freshly built NodeId per
service, one after the other (`typeid == ua.NodeId(ua.ObjectIds.X)`), and builds a list of seven more first
to tell session-less services. Publish comes 25th: about 30 NodeIds built and compared (~1.5-3.5 us each)
for every Publish request, of which a client subscribed to the fleet sends one per publishing interval
(50 a second at 20 ms). Publish is checked first here and served as asyncua serves it (its checks of the
session and the user's permission, its activity stamps, then its Publish branch, asyncua 2.1); every other
request goes through edge.opcua.large_responses (a large result list encoded in slices), then asyncua's own
dispatch.

`install` makes asyncua's binary server create GatewayProcessors for new connections (once per process).
"""

from __future__ import annotations

import time
from typing import Any

from asyncua import ua
from asyncua.server import binary_server_asyncio
from asyncua.server.uaprocessor import PublishRequestData
from asyncua.ua.ua_binary import struct_from_binary

from edge.opcua.large_responses import SlicedResponses

_PUBLISH = ua.NodeId(ua.ObjectIds.PublishRequest_Encoding_DefaultBinary)


class GatewayProcessor(SlicedResponses):
    """asyncua's processor of one connection's messages, with Publish dispatched first (other requests:
    edge.opcua.large_responses, then asyncua)."""

    async def _process_message(self, typeid: ua.NodeId, requesthdr: ua.RequestHeader, seqhdr: Any,
                               body: Any) -> bool:
        session = self.session
        if session is None or typeid != _PUBLISH:  # (no session: asyncua's refusal)
            return bool(await super()._process_message(typeid, requesthdr, seqhdr, body))
        permissions = self._connection.security_policy.permissions
        if permissions is not None and permissions.check_validity(session.user, typeid, body) is False:
            raise ua.uaerrors.BadUserAccessDenied
        self.session_last_activity = time.monotonic()
        session.touch()
        # asyncua's Publish branch
        params = struct_from_binary(ua.PublishParameters, body)
        subscriptions, results = session.publish(params.SubscriptionAcknowledgements)
        data = PublishRequestData(requesthdr=requesthdr, seqhdr=seqhdr, results=results)
        waiting = self._publish_results_subs  # subscriptions with a result waiting for a request: served now
        while waiting:
            subscription_id = next(iter(waiting))
            waiting.pop(subscription_id)
            subscription = session.subscription_service.subscriptions.get(subscription_id)
            if subscription is not None and await subscription.publish_results(data):
                break
        else:
            if len(self._publish_requests) >= self.publish_request_limit(subscriptions):
                self._evict_publish_request()
            self._publish_requests.append(data)
        return True


def install() -> None:
    """New connections of every asyncua server in this process get a GatewayProcessor."""
    binary_server_asyncio.UaProcessor = GatewayProcessor
