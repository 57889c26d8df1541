"""What the status endpoint, the status page and the live view read from the daemon (edge.service.daemon.Daemon
provides it): one protocol, so the page and the endpoint that serves it need not import each other."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol


class DaemonView(Protocol):
    """The daemon as its status readers see it."""

    @property
    def pollers(self) -> Mapping[str, Any]: ...  # machine id -> MachinePoller

    @property
    def publisher(self) -> Any: ...

    @property
    def commands(self) -> Any: ...


def spool_depth(daemon: DaemonView) -> int:
    """Rows waiting in the store-and-forward spool (the disk spool's `depth`; 0 for a spool that only drops)."""
    depth = getattr(daemon.publisher.spool, "depth", 0)
    return int(depth() if callable(depth) else depth)
