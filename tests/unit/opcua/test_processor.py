"""GatewayProcessor serves Publish as asyncua's UaProcessor does: the same responses (acknowledgement results,
sequence numbers, retransmission queue, keep-alives, faults) for the same requests, read and written by
edge.opcua.publish_wire, or by asyncua for a request in an encoding publish_wire leaves to it."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

import pytest
import pytest_asyncio
from asyncua import Server, ua
from asyncua.common.connection import TransportLimits
from asyncua.common.utils import Buffer
from asyncua.server.internal_session import SessionState
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary, struct_to_binary

from bench.opcua_publish import client_subscription
from edge.opcua import processor, subscriptions
from edge.opcua.processor import GatewayProcessor

pytestmark = pytest.mark.asyncio(loop_scope="module")
_NOTE = b"\x07\x00\x00\x00" + struct_to_binary(ua.DataValue(ua.Variant(2.5, ua.VariantType.Double)))
_MESSAGE_HEADERS = 12 + 4 + 8  # message header with channel id, token id, sequence header


class _Transport:
    def __init__(self) -> None:
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.written.append(data)

    def get_extra_info(self, _name: str) -> None:
        return None


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def server() -> AsyncIterator[Server]:
    server = Server()
    await server.init()
    subscriptions.install(server.iserver.subscription_service)
    yield server


def _publish(handle: int, acks: list[tuple[int, int]], unusual: bool = False) -> Buffer:
    request = ua.PublishRequest()
    request.RequestHeader.RequestHandle = handle
    request.RequestHeader.AuthenticationToken = ua.NodeId(1234, 1)
    if unusual:  # an AdditionalHeader with a body: publish_wire leaves the request to asyncua
        request.RequestHeader.AdditionalHeader = ua.ExtensionObject(TypeId=ua.NodeId(1, 1), Body=b"extra")
    request.Parameters.SubscriptionAcknowledgements = [
        ua.SubscriptionAcknowledgement(SubscriptionId=sid, SequenceNumber=seq) for sid, seq in acks]
    return Buffer(struct_to_binary(request))


def _decoded(data: bytes) -> Any:
    body = Buffer(data[_MESSAGE_HEADERS:])
    typeid = nodeid_from_binary(body.copy())
    kind = ua.PublishResponse if typeid.Identifier == ua.ObjectIds.PublishResponse_Encoding_DefaultBinary \
        else ua.ServiceFault
    response = struct_from_binary(kind, body)
    response.ResponseHeader.Timestamp = None
    if kind is ua.PublishResponse:
        response.Parameters.NotificationMessage.PublishTime = None
        response.Parameters.SubscriptionId = 0  # (each scenario's own)
    return response


async def _scenario(server: Server, kind: type[UaProcessor]) -> list[Any]:
    """Publish requests acknowledging known and unknown notifications, data and keep-alives, and a Publish
    without a subscription; the responses decoded, timestamps left out."""
    transport = _Transport()
    served = kind(server.iserver, transport, TransportLimits())
    session = served.session = server.iserver.create_session("test", external=True)
    session.state = SessionState.Activated  # (as ActivateSession leaves it)
    subscription = await client_subscription(session, served)
    sid = subscription.data.SubscriptionId
    await asyncio.sleep(0)  # the subscription's loop makes its first publish: it waits for a request
    assert sid in served._publish_results_subs
    seqhdr = ua.SequenceHeader()
    seqhdr.SequenceNumber, seqhdr.RequestId = 1, 9

    async def publish(handle: int, acks: list[tuple[int, int]], data: bool, unusual: bool = False) -> None:
        assert await served.process_message(seqhdr, _publish(handle, acks, unusual))
        if data:
            subscription._triggered_datachanges[1] = _NOTE
            await subscription.publish_results()

    await publish(1, [], data=False)  # answers the first publish at once: a keep-alive
    await publish(2, [], data=True)  # sequence number 1
    await publish(3, [], data=True)  # 2; 1 and 2 unacknowledged
    await publish(4, [(sid, 1), (sid + 1000, 2)], data=True)  # 3; 1 acknowledged, an unknown subscription
    await publish(5, [(sid, 2)], data=True, unusual=True)  # asyncua decodes it: 4; 2 acknowledged
    assert await served.process_message(seqhdr, _publish(6, [(sid, 3)]))
    assert subscription.republish(4).SequenceNumber == 4  # the retransmission queue kept 4, not 3
    await session.delete_subscriptions([sid])
    await publish(7, [(sid, 4)], data=False)  # no subscription left: a fault
    served._publish_requests.clear()
    return [_decoded(data) for data in transport.written]


async def test_publish_is_served_as_asyncua_serves_it(server: Server, monkeypatch: pytest.MonkeyPatch) -> None:
    read_here: list[int] = []
    read = processor.publish_request

    def spy(data: bytes) -> Any:
        request = read(data)
        if request is not None:
            read_here.append(request[0].RequestHandle)
        return request

    monkeypatch.setattr(processor, "publish_request", spy)
    ours = await _scenario(server, GatewayProcessor)
    assert read_here == [1, 2, 3, 4, 6, 7]
    assert ours == await _scenario(server, UaProcessor)
    assert [r.ResponseHeader.RequestHandle for r in ours] == [1, 2, 3, 4, 5, 7]
    assert [r.Parameters.NotificationMessage.SequenceNumber for r in ours[:5]] == [1, 1, 2, 3, 4]
    assert [r.Parameters.AvailableSequenceNumbers for r in ours[:5]] == [[], [1], [1, 2], [2, 3], [3, 4]]
    assert [status.value for status in ours[3].Parameters.Results] == [
        ua.StatusCodes.Good, ua.StatusCodes.BadSubscriptionIdInvalid]
    assert ours[5].ResponseHeader.ServiceResult.value == ua.StatusCodes.BadNoSubscription


@pytest.mark.parametrize("kind", [GatewayProcessor, UaProcessor])
async def test_a_session_not_activated_cannot_publish(server: Server, kind: type[UaProcessor]) -> None:
    """A Publish on a session created but never activated (no user checked) gets BadSessionNotActivated, its
    acknowledgements unread, as asyncua answers every service of such a session."""
    transport = _Transport()
    served = kind(server.iserver, transport, TransportLimits())
    owner = server.iserver.create_session("owner", external=True)
    subscription = await client_subscription(owner, served)
    sid = subscription.data.SubscriptionId
    subscription._not_acknowledged_results[5] = ua.PublishResult()
    served.session = server.iserver.create_session("intruder", external=True)
    seqhdr = ua.SequenceHeader()
    seqhdr.SequenceNumber, seqhdr.RequestId = 1, 9
    try:
        assert await served.process_message(seqhdr, _publish(1, [(sid, 5)]))
    finally:
        await owner.delete_subscriptions([sid])
    [fault] = [_decoded(data) for data in transport.written]
    assert fault.ResponseHeader.ServiceResult.value == ua.StatusCodes.BadSessionNotActivated
    assert list(subscription._not_acknowledged_results) == [5]
    assert not served._publish_requests
