"""A client's Publish request served without walking asyncua's chain of service comparisons, read and
answered in bytes written directly.

asyncua's UaProcessor finds a request's service by comparing its type id with a freshly built NodeId per
service, one after the other (`typeid == ua.NodeId(ua.ObjectIds.X)`), and builds a list of seven more first
to tell session-less services. Publish comes 25th: about 30 NodeIds built and compared (~1.5-3.5 us each)
for every Publish request, of which a client subscribed to the fleet sends one per publishing interval
(50 a second at 20 ms). Here a Publish request is recognised by its first bytes, its header and
acknowledgements are read and its response written by edge.opcua.publish_wire (asyncua's generic decoder
and encoder took 10-85 us each per Publish), the response sent in edge.opcua.secure_send's chunk. It is
served as asyncua serves it: its checks of the session, the user's permission and the session's activation
(main's short path for Publish left that one out), its activity stamps, the acknowledgements as its
SubscriptionService.publish takes them, then its Publish branch (asyncua 2.1). A request in an encoding
publish_wire does not read is decoded by asyncua and served the same way; every other request goes through
edge.opcua.large_responses (a large result list encoded in slices), then asyncua's own dispatch.

asyncua internals this relies on (the >=2.1,<2.2 pin): UaProcessor's process_message/_process_message split,
its `_publish_requests`, `_publish_results_subs`, `publish_request_limit` and `_evict_publish_request`,
forward_publish_response as the subscriptions' result callback, the session's `subscription_service` and its
`subscriptions`, InternalSubscription.publish(acks), PublishRequestData, and the message body's Buffer.

`install` makes asyncua's binary server create GatewayProcessors for new connections (once per process).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.server import binary_server_asyncio
from asyncua.server.uaprocessor import PublishRequestData
from asyncua.ua.ua_binary import struct_from_binary

from edge.opcua.large_responses import SlicedResponses
from edge.opcua.publish_wire import PUBLISH_TYPE, PublishHeader, publish_request, publish_response
from edge.opcua.secure_send import secure_message

_PUBLISH = ua.NodeId(ua.ObjectIds.PublishRequest_Encoding_DefaultBinary)
_GOOD = ua.StatusCodes.Good
_BAD_SUBSCRIPTION = ua.StatusCodes.BadSubscriptionIdInvalid
_logger = logging.getLogger(__name__)


class GatewayProcessor(SlicedResponses):
    """asyncua's processor of one connection's messages, with Publish read, dispatched and answered first
    (other requests: edge.opcua.large_responses, then asyncua)."""

    async def process_message(self, seqhdr: Any, body: Any) -> Any:
        request = None
        if self.session is not None and body.copy(4).read(4) == PUBLISH_TYPE:
            request = publish_request(body.copy().read(len(body)))
        if request is None:
            return await super().process_message(seqhdr, body)
        header, read, acks = request
        body.skip(read)
        try:
            return await self._process_message(_PUBLISH, header, seqhdr, body, acks)
        except (ServiceError, ua.uaerrors.UaStatusCodeError) as e:  # as asyncua's process_message answers
            _logger.error("sending service fault response to a Publish: %s", ua.StatusCode(e.code).name)
            self._fault(header, seqhdr, e.code)
        except Exception:
            _logger.exception("Error while processing a Publish request")
            self._fault(header, seqhdr, ua.StatusCodes.BadInternalError)
        return True

    def _fault(self, header: PublishHeader, seqhdr: Any, code: int) -> None:
        response = ua.ServiceFault()
        response.ResponseHeader.ServiceResult = ua.StatusCode(code)
        self.send_response(header.RequestHandle, seqhdr, response)

    async def _process_message(self, typeid: ua.NodeId, requesthdr: Any, seqhdr: Any, body: Any,
                               acks: list[tuple[int, int]] | None = None) -> bool:
        session = self.session
        if session is None or (typeid is not _PUBLISH and typeid != _PUBLISH):  # (no session: asyncua's refusal)
            return bool(await super()._process_message(typeid, requesthdr, seqhdr, body))
        permissions = self._connection.security_policy.permissions
        if permissions is not None and permissions.check_validity(session.user, typeid, body) is False:
            raise ua.uaerrors.BadUserAccessDenied
        self.session_last_activity = time.monotonic()
        session.touch()
        if not session.is_activated():  # as asyncua refuses every service of a session not activated
            raise ServiceError(ua.StatusCodes.BadSessionNotActivated)
        if acks is None:  # decoded by asyncua (an encoding publish_wire leaves to it)
            params = struct_from_binary(ua.PublishParameters, body)
            acks = [(ack.SubscriptionId, ack.SequenceNumber) for ack in params.SubscriptionAcknowledgements or ()]
        # asyncua's SubscriptionService.publish
        subscriptions = session.subscription_service.subscriptions
        if not subscriptions:
            raise ServiceError(ua.StatusCodes.BadNoSubscription)
        results = []
        for subscription_id, sequence_number in acks:
            acked = subscriptions.get(subscription_id)
            if acked is None:
                results.append(ua.StatusCode(_BAD_SUBSCRIPTION))
            else:
                acked.publish((sequence_number,))
                results.append(ua.StatusCode(_GOOD))
        # asyncua's Publish branch
        data = PublishRequestData(requesthdr=requesthdr, seqhdr=seqhdr, results=results)
        waiting = self._publish_results_subs  # subscriptions with a result waiting for a request: served now
        while waiting:
            subscription_id = next(iter(waiting))
            waiting.pop(subscription_id)
            subscription = subscriptions.get(subscription_id)
            if subscription is not None and await subscription.publish_results(data):
                break
        else:
            if len(self._publish_requests) >= self.publish_request_limit(len(subscriptions)):
                self._evict_publish_request()
            self._publish_requests.append(data)
        return True

    async def forward_publish_response(self, result: ua.PublishResult, requestdata: PublishRequestData) -> None:
        """asyncua's: the PublishResponse of `result` with the request's results, sent (publish_wire's bytes, in
        secure_send's chunk)."""
        result.Results = requestdata.results
        body = publish_response(requestdata.requesthdr.RequestHandle, result)
        self._transport.write(secure_message(self._connection, body, requestdata.seqhdr.RequestId))


def install() -> None:
    """New connections of every asyncua server in this process get a GatewayProcessor."""
    binary_server_asyncio.UaProcessor = GatewayProcessor
