"""Publish requests read and Publish responses written by edge.opcua.publish_wire are asyncua's bytes."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary, struct_to_binary
from hypothesis import given
from hypothesis import strategies as st

from edge.opcua import publish_wire
from edge.opcua.encoding import data_change_of_notes

NOW = datetime(2025, 11, 25, 12, 0, 0, 123456, tzinfo=UTC)
NOW_TICKS = ua.datetime_to_win_epoch(NOW)
PUBLISHED = datetime(2025, 11, 25, 12, 0, 0, 100000, tzinfo=UTC)


def asyncua_response(handle: int, result: ua.PublishResult) -> bytes:
    response = ua.PublishResponse(Parameters=result)
    response.ResponseHeader.RequestHandle = handle
    response.ResponseHeader.Timestamp = NOW
    return struct_to_binary(response)


def result_of(notifications: list[object], available: list[int], results: list[ua.StatusCode],
              sequence: int = 7, more: bool = False) -> ua.PublishResult:
    result = ua.PublishResult(SubscriptionId=42, AvailableSequenceNumbers=available, MoreNotifications=more)
    result.NotificationMessage = ua.NotificationMessage(SequenceNumber=sequence, PublishTime=PUBLISHED,
                                                        NotificationData=notifications)
    result.Results = results
    return result


def data_change() -> ua.ExtensionObject:
    value = ua.DataValue(ua.Variant(1.5, ua.VariantType.Double), SourceTimestamp=PUBLISHED, ServerTimestamp=NOW)
    note = struct_to_binary(ua.MonitoredItemNotification(ClientHandle=3, Value=value))
    return data_change_of_notes([note, [note, note]])


CASES = {
    "keep-alive": result_of([], [], []),
    "keep-alive with unacknowledged": result_of([], [5, 6], [ua.StatusCode()]),
    "data changes": result_of([data_change()], [7], [
        ua.StatusCode(), ua.StatusCode(ua.StatusCodes.BadSubscriptionIdInvalid)]),
    "asyncua's data change": result_of([ua.DataChangeNotification(MonitoredItems=[ua.MonitoredItemNotification(
        ClientHandle=9, Value=ua.DataValue(ua.Variant("x")))])], [1, 2, 3], []),
    "events and status": result_of([
        ua.EventNotificationList(Events=[ua.EventFieldList(ClientHandle=1, EventFields=[ua.Variant(5)])]),
        ua.StatusChangeNotification(Status=ua.StatusCode(ua.StatusCodes.BadTimeout))], [], [], more=True),
    "empty body": result_of([ua.ExtensionObject(TypeId=ua.NodeId(811), Body=b"")], [], []),
    "no body": result_of([ua.ExtensionObject(TypeId=ua.NodeId(811))], [], []),
    "null lists": result_of([], None, None),  # type: ignore[arg-type]
    "diagnostics": result_of([], [], [ua.StatusCode()]),
}
CASES["diagnostics"].DiagnosticInfos = [ua.DiagnosticInfo(SymbolicId=4)]


@pytest.mark.parametrize("name", list(CASES))
def test_response_is_asyncuas(name: str) -> None:
    result = CASES[name]
    assert publish_wire.publish_response(1234, result, NOW_TICKS) == asyncua_response(1234, result)


def test_response_timestamp_is_now() -> None:
    before = publish_wire.now_ticks()
    body = publish_wire.publish_response(1, result_of([], [], []))
    decoded = struct_from_binary(ua.ResponseHeader, Buffer(body[4:]))  # after the type id
    assert before <= ua.datetime_to_win_epoch(decoded.Timestamp) <= publish_wire.now_ticks()


def request_bytes(token: ua.NodeId, acks: list[tuple[int, int]] | None, audit: str | None = None,
                  additional: ua.ExtensionObject | None = None) -> bytes:
    request = ua.PublishRequest()
    request.RequestHeader = ua.RequestHeader(AuthenticationToken=token, Timestamp=NOW, RequestHandle=77,
                                             AuditEntryId=audit, TimeoutHint=15_000,
                                             AdditionalHeader=additional or ua.ExtensionObject())
    request.Parameters.SubscriptionAcknowledgements = None if acks is None else [
        ua.SubscriptionAcknowledgement(SubscriptionId=s, SequenceNumber=n) for s, n in acks]
    return struct_to_binary(request)


def asyncua_reads(data: bytes) -> tuple[int, int, list[tuple[int, int]], bytes]:
    body = Buffer(data)
    nodeid_from_binary(body)
    header = struct_from_binary(ua.RequestHeader, body)
    rest = body.copy().read(len(body))
    params = struct_from_binary(ua.PublishParameters, body)
    acks = [(a.SubscriptionId, a.SequenceNumber) for a in params.SubscriptionAcknowledgements or ()]
    return header.RequestHandle, header.TimeoutHint, acks, rest


TOKENS = [ua.NodeId(5), ua.NodeId(300, 1), ua.NodeId(2**32 - 1, 3), ua.NodeId("session-x", 2),
          ua.NodeId(b"\x01" * 32, 1, ua.NodeIdType.ByteString),
          ua.NodeId(ua.Guid("72962b91-fa75-4ae6-8d28-b404dc7daf63"), 1),
          ua.NodeId(b"", 1, ua.NodeIdType.ByteString)]


@pytest.mark.parametrize("token", TOKENS, ids=str)
@pytest.mark.parametrize("acks", [None, [], [(1, 2)], [(1, 2), (1, 3), (99, 2**32 - 1)]])
def test_request_read_as_asyncua_reads_it(token: ua.NodeId, acks: list[tuple[int, int]] | None) -> None:
    data = request_bytes(token, acks, audit="audit \u00e4" if acks else None)
    read = publish_wire.publish_request(data)
    assert read is not None
    header, header_end, got = read
    handle, timeout, expected, rest = asyncua_reads(data)
    assert (header.RequestHandle, header.TimeoutHint, got, data[header_end:]) == (handle, timeout, expected, rest)


def test_unread_encodings_left_to_asyncua() -> None:
    assert publish_wire.publish_request(request_bytes(ua.NodeId(5), [], additional=ua.ExtensionObject(
        TypeId=ua.NodeId(5), Body=b"x"))) is None
    assert publish_wire.publish_request(struct_to_binary(ua.ReadRequest())) is None
    assert publish_wire.publish_request(request_bytes(ua.NodeId(5), [(1, 2)])[:-3]) is None
    expanded = bytearray(request_bytes(ua.NodeId(5), []))
    expanded[4] |= 0x40  # ExpandedNodeId's server index flag on the token
    assert publish_wire.publish_request(bytes(expanded)) is None


u32 = st.integers(0, 2**32 - 1)


@given(st.lists(st.tuples(u32, u32), max_size=5), u32, st.text(max_size=8) | st.none(),
       st.lists(u32, max_size=6), st.lists(st.sampled_from([0, ua.StatusCodes.BadSubscriptionIdInvalid]), max_size=4),
       st.lists(st.binary(max_size=40), max_size=3), st.booleans())
def test_any_round_trip_matches_asyncua(acks: list[tuple[int, int]], handle: int, audit: str | None,
                                        available: list[int], codes: list[int], bodies: list[bytes],
                                        more: bool) -> None:
    data = request_bytes(ua.NodeId(handle, 1), acks, audit)
    read = publish_wire.publish_request(data)
    assert read is not None and read[2] == asyncua_reads(data)[2]
    result = result_of([ua.ExtensionObject(TypeId=ua.NodeId(811), Body=body) for body in bodies], available,
                       [ua.StatusCode(code) for code in codes], sequence=handle, more=more)
    assert publish_wire.publish_response(handle, result, NOW_TICKS) == asyncua_response(handle, result)
