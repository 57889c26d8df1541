"""One DataValue object for every equal attribute of the machines' nodes.

asyncua keeps each attribute of each node as its own DataValue, Variant and StatusCode (about 200 bytes),
and a variable has a dozen of them: a fleet of 100 machines with 74 metrics (each with its 40501 mirror)
holds ~15,000 variables whose DataType, ValueRank, AccessLevel, WriteMask, Historizing... are the same few
values, and whose BrowseName and DisplayName repeat from machine to machine. Sharing them keeps the
server's memory to what differs. asyncua never changes a stored attribute's DataValue in place (a write
replaces it), and neither does the gateway, so sharing is invisible to clients.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable
from typing import Any

from asyncua import ua

_VALUE = ua.AttributeIds.Value  # a metric's changing value: never shared here


class SharedAttributes:
    """Interns the static attributes of nodes as they are added."""

    def __init__(self) -> None:
        self._seen: dict[Hashable, ua.DataValue] = {}
        self.shared = 0  # attributes that now point at an equal one

    def share(self, nodes: Iterable[Any]) -> None:
        """Point each static attribute of `nodes` (asyncua NodeData) at the first equal one seen."""
        seen = self._seen
        for node in nodes:
            for attribute_id, attribute in node.attributes.items():
                if attribute_id == _VALUE:
                    continue
                value = attribute.value
                key = _key(attribute_id, value)
                if key is None:
                    continue
                first = seen.setdefault(key, value)
                if first is not value:
                    attribute.value = first
                    self.shared += 1

    def __len__(self) -> int:
        return len(self._seen)


def _key(attribute_id: int, value: ua.DataValue | None) -> Hashable | None:
    """What makes two attribute values the same to a client, or None when not worth (or safe) to compare."""
    if value is None or value.SourceTimestamp is not None or value.ServerTimestamp is not None:
        return None
    variant = value.Value
    if variant is None or variant.is_array or variant.Dimensions is not None:
        return None
    raw = variant.Value
    status = value.StatusCode.value if value.StatusCode is not None else None
    if isinstance(raw, ua.LocalizedText):
        return attribute_id, variant.VariantType, status, ua.LocalizedText, raw.Locale, raw.Text
    try:
        hash(raw)
    except TypeError:
        return None
    return attribute_id, variant.VariantType, status, type(raw), raw
