"""A CreateMonitoredItems request's items decoded chunk by chunk as they are created, not all at once.

asyncua decodes a request whole before serving it: 10,000 MonitoredItemCreateRequests took about 165 ms of
the daemon's loop in one go, before the creation itself (which edge.opcua.subscriptions serves in chunks with
the loop given turns between them). The request's last field is its items, so the decoder here reads the
subscription id, the timestamps asked for and the item count, and keeps the rest of the message for
`PendingItems.take`, which decodes the next chunk with asyncua's own decoder. Anything that reads the items
otherwise (asyncua's path, a callback) gets them all decoded at first access: the same objects asyncua makes.

`install` swaps asyncua's struct decoder lookup for one that answers this type and delegates every other.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, overload

from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua import ua_binary

_Decoder = Callable[[Any], Any]


class PendingItems(Sequence[ua.MonitoredItemCreateRequest]):
    """The items of a CreateMonitoredItems request, decoded on demand from what remains of its message."""

    def __init__(self, count: int, rest: Buffer, decode_item: _Decoder) -> None:
        self._count = count
        self._rest = rest
        self._decode_item = decode_item
        self._decoded: list[ua.MonitoredItemCreateRequest] = []

    def take(self, count: int) -> list[ua.MonitoredItemCreateRequest]:
        """The next `count` items (fewer at the end), decoded now."""
        start = len(self._decoded)
        stop = min(self._count, start + count)
        decode, rest = self._decode_item, self._rest
        self._decoded.extend(decode(rest) for _ in range(start, stop))
        return self._decoded[start:stop]

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, index: int) -> ua.MonitoredItemCreateRequest: ...

    @overload
    def __getitem__(self, index: slice) -> list[ua.MonitoredItemCreateRequest]: ...

    def __getitem__(self, index: int | slice) -> Any:
        self.take(self._count)
        return self._decoded[index]

    def __iter__(self) -> Iterator[ua.MonitoredItemCreateRequest]:
        self.take(self._count)
        return iter(self._decoded)


def _parameters_decoder(decode: Callable[[Any], _Decoder]) -> _Decoder:
    subscription_id = ua_binary.Primitives.UInt32.unpack
    count_of = ua_binary.Primitives.Int32.unpack
    timestamps = decode(ua.TimestampsToReturn)
    item = decode(ua.MonitoredItemCreateRequest)

    def decode_parameters(data: Buffer) -> ua.CreateMonitoredItemsParameters:
        params = ua.CreateMonitoredItemsParameters(SubscriptionId=subscription_id(data),
                                                   TimestampsToReturn=timestamps(data))
        count = count_of(data)  # -1: a null array, as asyncua reads it: no item
        params.ItemsToCreate = PendingItems(max(count, 0), data.copy(), item)
        return params

    return decode_parameters


def install() -> None:
    """Make asyncua decode CreateMonitoredItemsParameters with PendingItems (once per process)."""
    current = ua_binary._create_dataclass_deserializer
    if getattr(current, "pending_items", False):
        return
    parameters = _parameters_decoder(current)

    def deserializer(objtype: Any) -> _Decoder:
        if objtype is ua.CreateMonitoredItemsParameters:
            return parameters
        return current(objtype)

    deserializer.pending_items = True  # type: ignore[attr-defined]
    ua_binary._create_dataclass_deserializer = deserializer
