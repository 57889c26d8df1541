"""Large responses encoded a slice of results at a time, the daemon's loop given turns between slices.

asyncua encodes a response whole, through its generic serializer (~8 us a MonitoredItemCreateResult, ~30 us
a browse result): the response to 10,000 monitored items created at once held the daemon's loop 80-150 ms
in one go, a Browse of 500 folders 50-150 ms, after the work itself (which edge.opcua.subscriptions and
edge.opcua.sessions serve in slices). `SlicedResponses` lets asyncua serve Browse, Read,
TranslateBrowsePaths, CreateMonitoredItems and DeleteMonitoredItems as it does, keeps a response of more than
SLICED_RESULTS results instead of sending it, and encodes its results a slice at a time (edge.opcua.turns). The
bytes are asyncua's own (the same fields in the same order: tests/unit/opcua/test_large_responses.py compares them),
signed, encrypted and sent at once, as one message.

The connection serves its next request only after this one's response is sent, as before; other
connections and the poll loop run between slices. A subscription whose CreateMonitoredItems is being served
or its response encoded holds back its data changes (`GatewaySubscription.creating`), so no notification of
an item reaches the client before the response that tells it the item exists.

edge.opcua.processor's GatewayProcessor, the class asyncua's binary server is given, builds on this one.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from asyncua import ua
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua import ua_binary

from edge.opcua import sessions
from edge.opcua.turns import slices

# a response of more results than this is encoded in slices (edge.opcua.turns); fewer take a ms at most
SLICED_RESULTS = 64
_COUNT = ua_binary.Primitives.Int32.pack
_SUBSCRIPTION_ID = ua_binary.Primitives.UInt32.unpack
# the requests whose responses are a list of results per operation, encoded in chunks past ENCODE_CHUNK
_CHUNKED = frozenset(ua.NodeId(getattr(ua.ObjectIds, f"{name}Request_Encoding_DefaultBinary")) for name in (
    "Browse", "Read", "TranslateBrowsePathsToNodeIds", "CreateMonitoredItems", "DeleteMonitoredItems"))
# a MonitoredItemCreateResult: StatusCode, MonitoredItemId, RevisedSamplingInterval, RevisedQueueSize, then a
# null FilterResult (a two-byte NodeId 0 and no body: three zero bytes)
_CREATED = struct.Struct("<IIdI3x")
_CREATE_ITEMS = ua.NodeId(ua.ObjectIds.CreateMonitoredItemsRequest_Encoding_DefaultBinary)


async def encode_results(response: Any) -> bytes:
    """`struct_to_binary(response)` of a response whose last two fields are Results and DiagnosticInfos,
    with the results encoded a slice at a time, the loop given turns between slices (edge.opcua.turns)."""
    results: Sequence[Any] = response.Results
    response.Results = []
    try:
        empty = ua_binary.struct_to_binary(response)  # ... results: Int32 0, then the diagnostics
    finally:
        response.Results = results
    diagnostics = len(ua_binary.list_to_binary(ua.DiagnosticInfo, response.DiagnosticInfos))
    head, tail = empty[:len(empty) - diagnostics - 4], empty[len(empty) - diagnostics:]
    parts = [head, _COUNT(len(results))]
    if results:
        encode = _result_encoder(type(results[0]))
        async for chunk in slices(results):
            parts.extend(map(encode, chunk))
    parts.append(tail)
    return b"".join(parts)


def _result_encoder(kind: type) -> Callable[[Any], bytes]:
    """asyncua's serializer of `kind`; for a MonitoredItemCreateResult with no filter result (every item the
    gateway creates but one with a filter) one struct pack of its four numbers and the null ExtensionObject,
    the same bytes: asyncua's took ~2 us a result, a sixth of a monitored item's whole cost."""
    generic: Callable[[Any], bytes] = ua_binary.create_type_serializer(kind)
    if kind is not ua.MonitoredItemCreateResult:
        return generic
    pack = _CREATED.pack

    def encode(result: ua.MonitoredItemCreateResult) -> bytes:
        found = result.FilterResult
        if found is None or (type(found) is ua.ExtensionObject and found.Body is None
                             and found.TypeId.NodeIdType == ua.NodeIdType.TwoByte and found.TypeId.Identifier == 0):
            return pack(result.StatusCode.value, result.MonitoredItemId, result.RevisedSamplingInterval,
                        result.RevisedQueueSize)
        return generic(result)

    return encode


class SlicedResponses(UaProcessor):
    """asyncua's processor of one connection, sending large result lists encoded in chunks."""

    _held: tuple[Any, list[tuple[int, Any]]] | None = None  # (request's seqhdr, its responses kept)

    async def _process_message(self, typeid: ua.NodeId, requesthdr: Any, seqhdr: Any, body: Any) -> Any:
        sessions.adopt(self.session)  # (None before CreateSession: left alone)
        if typeid not in _CHUNKED:
            return await super()._process_message(typeid, requesthdr, seqhdr, body)
        with self._creating(typeid, body):
            kept: list[tuple[int, Any]] = []
            self._held = (seqhdr, kept)
            try:
                answer = await super()._process_message(typeid, requesthdr, seqhdr, body)
            finally:
                self._held = None
            for handle, response in kept:
                await self._send_chunked(handle, seqhdr, response)
        return answer

    def send_response(self, requesthandle: int, seqhdr: Any, response: Any,
                      msgtype: ua.MessageType = ua.MessageType.SecureMessage) -> None:
        held = self._held
        if (held is not None and seqhdr is held[0] and msgtype == ua.MessageType.SecureMessage
                and len(getattr(response, "Results", None) or ()) > SLICED_RESULTS):
            held[1].append((requesthandle, response))  # the request being served: sent once encoded
            return
        super().send_response(requesthandle, seqhdr, response, msgtype)

    async def _send_chunked(self, requesthandle: int, seqhdr: Any, response: Any) -> None:
        response.ResponseHeader.RequestHandle = requesthandle
        body = await encode_results(response)
        data = self._connection.message_to_binary(body, message_type=ua.MessageType.SecureMessage,
                                                  request_id=seqhdr.RequestId)
        self._transport.write(data)

    @contextlib.contextmanager
    def _creating(self, typeid: ua.NodeId, body: Any) -> Iterator[None]:
        """While a CreateMonitoredItems request is served and its response sent, its subscription (one of the
        gateway's, edge.opcua.subscriptions) holds back its data changes."""
        subscription = None
        if typeid == _CREATE_ITEMS:
            with contextlib.suppress(Exception):  # a body too short: asyncua answers it as it does
                subscription_id = _SUBSCRIPTION_ID(body.copy())
                subscription = self.iserver.subscription_service.subscriptions.get(subscription_id)
        if subscription is None or not hasattr(subscription, "creating"):
            yield
            return
        subscription.creating += 1
        try:
            yield
        finally:
            subscription.creating -= 1

