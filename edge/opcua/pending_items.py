"""A CreateMonitoredItems request's items decoded chunk by chunk as they are created, not all at once.

asyncua decodes a request whole before serving it: 10,000 MonitoredItemCreateRequests took about 165 ms of
the daemon's loop in one go, before the creation itself (which edge.opcua.subscriptions serves in chunks with
the loop given turns between them). The request's last field is its items, so the decoder here reads the
subscription id, the timestamps asked for and the item count, and keeps the rest of the message for
`PendingItems.take`, which decodes the next chunk with asyncua's own decoder. Anything that reads the items
otherwise (asyncua's path, a callback) gets them all decoded at first access: the same objects asyncua makes.

The same holds for the other requests of many operations whose operations are the message's last field:
Browse (500 BrowseDescriptions took 30-50 ms to decode), Read and TranslateBrowsePaths, which
edge.opcua.sessions serves a slice at a time (`take`).

`install` swaps asyncua's struct decoder lookup for one that answers these types and delegates every other.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar, overload

from asyncua import ua
from asyncua.common.utils import Buffer
from asyncua.ua import ua_binary

from edge.opcua.item_decoding import fast_items

_Decoder = Callable[[Any], Any]
T = TypeVar("T")


class PendingItems(Sequence[T]):
    """The operations of a request (the items of a CreateMonitoredItems), decoded on demand from what remains
    of its message."""

    def __init__(self, count: int, rest: Buffer, decode_item: _Decoder) -> None:
        self._count = count
        self._rest = rest
        self._decode_item = decode_item
        self._decoded: list[T] = []

    def take(self, count: int) -> list[T]:
        """The next `count` items (fewer at the end), decoded now."""
        start = len(self._decoded)
        stop = min(self._count, start + count)
        decode, rest = self._decode_item, self._rest
        self._decoded.extend(decode(rest) for _ in range(start, stop))
        return self._decoded[start:stop]

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, index: int) -> T: ...

    @overload
    def __getitem__(self, index: slice) -> list[T]: ...

    def __getitem__(self, index: int | slice) -> Any:
        self.take(self._count)
        return self._decoded[index]

    def __iter__(self) -> Iterator[T]:
        self.take(self._count)
        return iter(self._decoded)


def _parameters_decoder(decode: Callable[[Any], _Decoder]) -> _Decoder:
    subscription_id = ua_binary.Primitives.UInt32.unpack
    timestamps = decode(ua.TimestampsToReturn)
    item = fast_items(decode(ua.MonitoredItemCreateRequest))  # (the usual item read at once, edge.opcua.item_decoding)

    def decode_parameters(data: Buffer) -> ua.CreateMonitoredItemsParameters:
        params = ua.CreateMonitoredItemsParameters(SubscriptionId=subscription_id(data),
                                                   TimestampsToReturn=timestamps(data))
        params.ItemsToCreate = _pending(data, item)
        return params

    return decode_parameters


def _pending(data: Buffer, decode_item: _Decoder) -> PendingItems[Any]:
    count = ua_binary.Primitives.Int32.unpack(data)  # -1: a null array, as asyncua reads it: no operation
    return PendingItems(max(count, 0), data.copy(), decode_item)


def _browse_decoder(decode: Callable[[Any], _Decoder]) -> _Decoder:
    view, counter, item = decode(ua.ViewDescription), ua_binary.Primitives.UInt32.unpack, decode(ua.BrowseDescription)

    def decode_parameters(data: Buffer) -> ua.BrowseParameters:
        params = ua.BrowseParameters(View=view(data), RequestedMaxReferencesPerNode=counter(data))
        params.NodesToBrowse = _pending(data, item)
        return params

    return decode_parameters


def _read_decoder(decode: Callable[[Any], _Decoder]) -> _Decoder:
    max_age, timestamps = ua_binary.Primitives.Double.unpack, decode(ua.TimestampsToReturn)
    item = decode(ua.ReadValueId)

    def decode_parameters(data: Buffer) -> ua.ReadParameters:
        params = ua.ReadParameters(MaxAge=max_age(data), TimestampsToReturn=timestamps(data))
        params.NodesToRead = _pending(data, item)
        return params

    return decode_parameters


def _translate_decoder(decode: Callable[[Any], _Decoder]) -> _Decoder:
    item = decode(ua.BrowsePath)

    def decode_parameters(data: Buffer) -> ua.TranslateBrowsePathsToNodeIdsParameters:
        return ua.TranslateBrowsePathsToNodeIdsParameters(BrowsePaths=_pending(data, item))

    return decode_parameters


def install() -> None:
    """Make asyncua decode CreateMonitoredItems, Browse, Read and TranslateBrowsePaths parameters with
    PendingItems (once per process)."""
    current = ua_binary._create_dataclass_deserializer
    if getattr(current, "pending_items", False):
        return
    lazy = {ua.CreateMonitoredItemsParameters: _parameters_decoder(current),
            ua.BrowseParameters: _browse_decoder(current), ua.ReadParameters: _read_decoder(current),
            ua.TranslateBrowsePathsToNodeIdsParameters: _translate_decoder(current)}

    def deserializer(objtype: Any) -> _Decoder:
        decode = lazy.get(objtype)
        return decode if decode is not None else current(objtype)

    deserializer.pending_items = True  # type: ignore[attr-defined]
    ua_binary._create_dataclass_deserializer = deserializer
