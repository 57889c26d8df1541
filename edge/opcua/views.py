"""Browse and TranslateBrowsePaths without walking the reference type tree once per reference.

asyncua checks whether a reference is of the type a client asks for (usually HierarchicalReferences, with
its subtypes) by walking that type's HasSubtype tree again for every reference it looks at: ~250 us a
reference, so a client browsing 500 folders of the gateway's tree in one request held the daemon's loop
about half a second (bench `opcua --diagnose`). `GatewayViewService` answers the same question from the
type's subtypes gathered once per call (a set), which gives the same answers as long as no reference type
is added during the call: none is (a call runs without awaiting). A request served in slices
(edge.opcua.sessions) keeps one cache for all its slices: a reference type added meanwhile (the gateway adds
none after starting) would be seen from its next request on.
"""

from __future__ import annotations

from typing import Any

from asyncua import ua
from asyncua.server.address_space import ViewService

_NULL = ua.NodeId(ua.ObjectIds.Null)
Subtypes = dict[ua.NodeId, frozenset[ua.NodeId]]  # a reference type -> its subtypes (transitively)


class GatewayViewService(ViewService):
    """asyncua's view service with each reference type's subtypes gathered once per call."""

    _subtypes: Subtypes | None = None

    def browse(self, params: ua.BrowseParameters, subtypes: Subtypes | None = None) -> list[ua.BrowseResult]:
        """asyncua's; `subtypes`: the cache to use (one request served in slices shares one), else a new one."""
        self._subtypes = {} if subtypes is None else subtypes
        try:
            return super().browse(params)
        finally:
            self._subtypes = None

    def translate_browsepaths_to_nodeids(self, browsepaths: list[ua.BrowsePath],
                                         subtypes: Subtypes | None = None) -> list[ua.BrowsePathResult]:
        self._subtypes = {} if subtypes is None else subtypes
        try:
            return super().translate_browsepaths_to_nodeids(browsepaths)
        finally:
            self._subtypes = None

    def _suitable_reftype(self, ref1: ua.NodeId, ref2: ua.NodeId, subtypes: bool) -> bool:
        if ref1 in (_NULL, ref2):  # no type asked: every reference (includeSubtypes ignored)
            return True
        return subtypes and ref2 in self._subtypes_of(ref1)

    def _subtypes_of(self, ref: ua.NodeId) -> frozenset[ua.NodeId]:
        cache = self._subtypes
        if cache is None:  # called outside browse/translate (asyncua's own use): as asyncua does
            return frozenset(self._get_sub_ref(ref))
        found = cache.get(ref)
        if found is None:
            found = cache[ref] = frozenset(self._get_sub_ref(ref))
        return found


def install(iserver: Any) -> None:
    """Make the server's view service a GatewayViewService (no state of its own between calls)."""
    if type(iserver.view_service) is ViewService:
        iserver.view_service.__class__ = GatewayViewService

