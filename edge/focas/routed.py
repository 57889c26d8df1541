"""One machine over two transports: native FOCAS/Ethernet first, the FOCAS library host for the rest.

The native wire has no public code for alarm history or parameter writes; the library host (the packed
surface served by `focas-edge fwlib-host`) has them but is one more process and one more hop. A routed
session sends each function to the transport that has it, native preferred: every fast poll stays one
batched native round trip, and only what the native side lacks goes to the library host.

The native session is the machine's session: if it fails, the routed session fails and reconnects as any
session does. The library host is an accessory: while it is down, only the items routed to it fail (their
own error, per item), and it is reconnected on the next use.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence
from datetime import datetime
from typing import Any, ClassVar

from edge.focas import items as it
from edge.focas.errors import EW_SOCKET, CncError, ConnectionLost, FocasError, NotSupported
from edge.focas.model import Capabilities, SysInfo
from edge.focas.outage import ConnectOutage
from edge.focas.session import CncSession, ItemResult

log = logging.getLogger(__name__)

NATIVE = "native"
LIBRARY = "fwlib-host"


class RoutedSession(CncSession):
    """A CncSession over a native session and a library-host session; `route(op)` says which answers."""

    transport: ClassVar[str] = "focas+fwlib"

    def __init__(self, native: CncSession, library: CncSession, **timeouts: Any) -> None:
        super().__init__(**timeouts)
        self.native = native
        self.library = library
        self._library_connect: asyncio.Task[None] | None = None
        # Retried on every tick that needs it while down: a WARNING each time would flood the journal.
        self._library_outage = ConnectOutage(f"library host peer={library.describe()}", log)

    def describe(self) -> str:
        return f"{self.native.describe()} + {self.library.describe()}"

    @property
    def capabilities(self) -> Capabilities:
        supported = self.native.capabilities.supported | self.library.capabilities.supported
        return Capabilities(self.transport, supported)

    def route(self, operation: str) -> str | None:
        """NATIVE or LIBRARY for an operation (a read item's or a write's name); None if neither has it."""
        if self.native.capabilities.can(operation):
            return NATIVE
        if self.library.capabilities.can(operation):
            return LIBRARY
        return None

    # ---- lifecycle -------------------------------------------------------------------------------------
    async def _open(self) -> SysInfo:
        sysinfo = await self.native.connect()
        self._library_up()
        if self._library_connect is not None:  # give it part of the connect budget, so the first tick has it
            await asyncio.wait({self._library_connect}, timeout=self.connect_timeout / 2)
        return sysinfo

    def _library_up(self) -> bool:
        """Whether the library host is connected; if not, (re)connect it in the background.

        Never waits: a library host that is down or slow to answer must not hold up the native batch (or
        run it into the session timeout, which would reset the native connection too).
        """
        if self.library.connected:
            return True
        if self._library_connect is None or self._library_connect.done():
            self._library_connect = asyncio.create_task(self._connect_library(), name="fwlib-host-connect")
        return False

    async def _connect_library(self) -> None:
        try:
            await self.library.connect()
        except FocasError as exc:
            self._library_outage.failed(f"{exc} (only the functions routed to it fail)")
        else:
            self._library_outage.connected()

    async def _close(self) -> None:
        if self._library_connect is not None:
            self._library_connect.cancel()
            await asyncio.gather(self._library_connect, return_exceptions=True)
            self._library_connect = None
        await asyncio.gather(self.native.close(), self.library.close(), return_exceptions=True)

    # ---- reads -----------------------------------------------------------------------------------------
    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        results: list[ItemResult] = [None] * len(items)
        native_at = [i for i, item in enumerate(items) if self.route(item.operation) != LIBRARY]
        library_at = [i for i, item in enumerate(items) if self.route(item.operation) == LIBRARY]
        if library_at and self._library_up():
            library_task = asyncio.ensure_future(self.library.batch([items[i] for i in library_at]))
        else:
            library_task = None
        try:
            native_results = await self.native.batch([items[i] for i in native_at]) if native_at else []
        except BaseException:
            if library_task is not None:
                library_task.cancel()
            raise
        for i, result in zip(native_at, native_results, strict=True):
            results[i] = result
        library_results: list[ItemResult]
        if library_task is None:
            error = ConnectionLost(f"{self.library.describe()}: library host not connected")
            library_results = [error] * len(library_at)
        else:
            try:
                library_results = await library_task
            except FocasError as exc:  # the library host failed: its items fail, the native ones stand
                library_results = [exc] * len(library_at)
        for i, result in zip(library_at, library_results, strict=True):
            results[i] = result
        return results

    # ---- writes: each raw write on the transport that has it, under that session's own lock -------------
    def _writer(self, operation: str) -> CncSession:
        route = self.route(operation)
        if route is None:
            raise NotSupported(operation, "neither the native transport nor the library host has it")
        return self.native if route == NATIVE else self.library

    async def _write_on(self, operation: str, call: Any) -> None:
        session = self._writer(operation)
        if session is self.library and not self._library_up():
            call.close()
            raise CncError(EW_SOCKET, operation, message=f"{self.library.describe()}: library host not connected; "
                                                         f"nothing was written")
        await session._locked_write(call)

    async def _write_macro(self, number: int, value: float) -> None:
        session = self._writer("write_macro")
        await self._write_on("write_macro", session._write_macro(number, value))

    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:
        session = self._writer("write_pmc")
        await self._write_on("write_pmc", session._write_pmc_bytes(area, start, data))

    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None:
        session = self._writer("write_param")
        await self._write_on("write_param", session._write_param(number, axis, ptype, value))

    async def _set_clock(self, when: datetime) -> None:
        session = self._writer("set_clock")
        await self._write_on("set_clock", session._set_clock(when))
