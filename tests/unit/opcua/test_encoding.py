"""The gateway's own encoding of DataValues and DataChangeNotifications is byte for byte asyncua's."""

from __future__ import annotations

import contextvars
import dataclasses
from datetime import UTC, datetime, timedelta

import pytest
from asyncua import ua
from asyncua.ua.ua_binary import (
    extensionobject_to_binary,
    set_string_encoding,
    struct_from_binary,
    struct_to_binary,
)

from edge.opcua import encoding
from edge.opcua.values import ServerTime, SharedDataValue, data_value, offline_value, server_now
from edge.samples import MetricType, Quality, Sample

CNC_MS = 1_764_072_000_123  # 2025-11-25 12:00:00.123 UTC

SAMPLES = [
    Sample("b", True, MetricType.BOOLEAN, CNC_MS),
    Sample("i8", -128, MetricType.INT8, CNC_MS),
    Sample("i16", -32768, MetricType.INT16, CNC_MS),
    Sample("i32", 2**31 - 1, MetricType.INT32, CNC_MS),
    Sample("i64", -(2**63), MetricType.INT64, CNC_MS),
    Sample("u8", 255, MetricType.UINT8, CNC_MS),
    Sample("u16", 65535, MetricType.UINT16, CNC_MS),
    Sample("u32", 2**32 - 1, MetricType.UINT32, CNC_MS),
    Sample("u64", 2**64 - 1, MetricType.UINT64, CNC_MS),
    Sample("f", 0.1, MetricType.FLOAT, CNC_MS),
    Sample("d", -1.5e300, MetricType.DOUBLE, CNC_MS),
    Sample("d-int", 7, MetricType.DOUBLE, CNC_MS),
    Sample("s", "O1234 \u00c4 \U0001f600", MetricType.STRING, CNC_MS),
    Sample("s-empty", "", MetricType.STRING, CNC_MS),
    Sample("s-surrogate", "O\udcff1", MetricType.STRING, CNC_MS),  # an undecodable byte kept, as asyncua does
    Sample("t", CNC_MS - 5000, MetricType.DATETIME, CNC_MS),
    Sample("stale", 3, MetricType.INT32, CNC_MS, Quality.STALE),
    Sample("bad", 3, MetricType.INT32, CNC_MS, Quality.BAD),
    Sample("none", None, MetricType.DOUBLE, CNC_MS),
    Sample("mismatch", "x", MetricType.INT32, CNC_MS),
    Sample("too-big", 40_000, MetricType.INT16, CNC_MS),  # outside the node's type: Bad, never a broken publish
    Sample("old", -11_644_473_600_000, MetricType.INT32, 0),
]


def _plain(value: ua.DataValue) -> ua.DataValue:
    """The same DataValue built through asyncua's own constructor (its checks and type guessing)."""
    variant = value.Value
    return ua.DataValue(ua.Variant(variant.Value, variant.VariantType),
                        StatusCode=ua.StatusCode(value.StatusCode.value),
                        SourceTimestamp=value.SourceTimestamp, ServerTimestamp=value.ServerTimestamp)


@pytest.mark.parametrize("sample", SAMPLES, ids=[s.name for s in SAMPLES])
def test_a_values_encoding_is_asyncuas(sample: Sample) -> None:
    value = data_value(sample, server_now())
    assert value.encoded == struct_to_binary(value) == struct_to_binary(_plain(value))
    decoded = struct_from_binary(ua.DataValue, ua.utils.Buffer(value.encoded))
    assert struct_to_binary(decoded) == value.encoded  # (a Float decodes to its float32 value)


def test_the_fast_builder_sets_every_field_as_the_constructor_does() -> None:
    value = data_value(Sample("d", 2.5, MetricType.DOUBLE, CNC_MS), server_now())
    built = _plain(value)
    for field in dataclasses.fields(ua.DataValue):
        assert getattr(value, field.name) == getattr(built, field.name), field.name
    assert value.SourceTimestamp == datetime(2025, 11, 25, 12, 0, 0, 123000, tzinfo=UTC)


def test_status_follows_quality_and_bad_carries_no_value() -> None:
    now = server_now()
    by_name = {s.name: data_value(s, now) for s in SAMPLES}
    assert by_name["d"].StatusCode.value == ua.StatusCodes.Good
    assert by_name["stale"].StatusCode.value == ua.StatusCodes.UncertainLastUsableValue
    assert by_name["stale"].Value.Value == 3
    assert by_name["bad"].StatusCode.value == ua.StatusCodes.Bad and by_name["bad"].Value.Value is None
    assert by_name["too-big"].StatusCode.value == ua.StatusCodes.BadTypeMismatch
    offline = offline_value(now)
    assert offline.encoded == struct_to_binary(offline)


@pytest.mark.parametrize("epoch_ms", [-11_644_473_600_001, -11_644_473_600_000, 0, CNC_MS, 253_402_300_798_999,
                                      253_402_300_799_000])
def test_ticks_are_asyncuas_datetime_conversion(epoch_ms: int) -> None:
    when = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(milliseconds=epoch_ms)
    assert encoding.ticks(epoch_ms) == ua.datetime_to_win_epoch(when)


def test_ticks_beyond_pythons_datetime_are_opc_uas_maximum() -> None:
    """Year 10000 has no Python datetime; OPC UA's rule is to send the maximum DateTime, as for 9999-12-31."""
    last = ua.datetime_to_win_epoch(datetime(1970, 1, 1, tzinfo=UTC) + timedelta(milliseconds=253_402_300_799_000))
    assert encoding.ticks(253_402_300_800_000) == encoding.ticks(10**15) == last


def test_a_data_change_notification_is_asyncuas() -> None:
    now = server_now()
    pairs: list[tuple[int, ua.DataValue]] = [(index * 7919, data_value(s, now)) for index, s in enumerate(SAMPLES)]
    waiting = SharedDataValue(ua.Variant(None), StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData),
                              ServerTimestamp=now.when)  # not built by data_value: asyncua encodes it
    pairs.append((2**32 - 1, waiting))
    pairs.append((5, ua.DataValue(ua.Variant([1, 2], ua.VariantType.Int32))))
    theirs = ua.DataChangeNotification(MonitoredItems=[ua.MonitoredItemNotification(ClientHandle=h, Value=v)
                                                       for h, v in pairs])
    ours = encoding.data_change_notification(pairs)
    assert extensionobject_to_binary(ours) == extensionobject_to_binary(theirs)
    assert extensionobject_to_binary(encoding.data_change_notification([])) == \
        extensionobject_to_binary(ua.DataChangeNotification())


def test_a_publish_response_is_asyncuas() -> None:
    now = datetime(2026, 1, 1, 0, 0, 0, 1, tzinfo=UTC)
    server = ServerTime(now, ua.datetime_to_win_epoch(now))
    pairs: list[tuple[int, ua.DataValue]] = [(1, data_value(SAMPLES[0], server))]

    def response(notification: object) -> bytes:
        result = ua.PublishResult(SubscriptionId=78, AvailableSequenceNumbers=[3, 4])
        result.NotificationMessage.SequenceNumber = 4
        result.NotificationMessage.PublishTime = datetime(2026, 1, 1, tzinfo=UTC)
        result.NotificationMessage.NotificationData.append(notification)
        response = ua.PublishResponse(Parameters=result)
        response.ResponseHeader.Timestamp = datetime(2026, 1, 1, tzinfo=UTC)
        return struct_to_binary(response)

    theirs = ua.DataChangeNotification(MonitoredItems=[ua.MonitoredItemNotification(ClientHandle=h, Value=v)
                                                       for h, v in pairs])
    assert response(encoding.data_change_notification(pairs)) == response(theirs)


def test_queued_notes_make_asyncuas_notification_whatever_their_form() -> None:
    now = server_now()
    pairs: list[tuple[int, ua.DataValue]] = [(index * 7919, data_value(s, now)) for index, s in enumerate(SAMPLES)]
    pairs.append((5, ua.DataValue(ua.Variant([1, 2], ua.VariantType.Int32))))
    theirs = extensionobject_to_binary(ua.DataChangeNotification(
        MonitoredItems=[ua.MonitoredItemNotification(ClientHandle=h, Value=v) for h, v in pairs]))
    encoded = [encoding.handle_prefix(h) + encoding.data_value_bytes(v) for h, v in pairs]
    assert extensionobject_to_binary(encoding.data_change_of_notes([encoded[:3], encoded[3:]])) == theirs
    assert extensionobject_to_binary(encoding.data_change_of_notes(encoded)) == theirs  # each queued bare
    assert extensionobject_to_binary(encoding.data_change_of_notes([encoded[0], encoded[1:4], *encoded[4:]])) == theirs
    mixed: list[list[object]] = [[encoded[0], pairs[1]], [ua.MonitoredItemNotification(ClientHandle=h, Value=v)
                                                          for h, v in pairs[2:]]]
    assert extensionobject_to_binary(encoding.data_change_of_notes(mixed)) == theirs
    assert extensionobject_to_binary(encoding.data_change_of_notes([])) == \
        extensionobject_to_binary(ua.DataChangeNotification())


def test_a_string_is_encoded_in_asyncuas_configured_encoding() -> None:
    """The string encoder writes the bytes itself: it must follow asyncua's string encoding setting as
    Primitives.String.pack does (a context variable, set here in a copy of the context only)."""
    def encoded() -> tuple[bytes, bytes]:
        set_string_encoding("latin-1")
        value = data_value(Sample("s", "O\u00c4", MetricType.STRING, CNC_MS), server_now())
        return value.encoded, struct_to_binary(_plain(value))

    ours, asyncuas = contextvars.copy_context().run(encoded)
    assert ours == asyncuas and b"O\xc4" in ours
