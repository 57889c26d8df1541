"""The FOCAS library host: the packed surface, served for each CNC through FANUC's library.

One process, one loaded library, one worker (thread + handle) and one packed endpoint per CNC. The
endpoint is the same listener the simulator uses (edge.focas.packed.endpoint), so the daemon's
`transport: packed` cannot tell the two apart except by what is behind them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from edge.focas.packed.endpoint import PackedEndpoint, start_packed_endpoint
from edge.fwlib.library import FocasLibrary, LibraryLoadError
from edge.fwlib.settings import HostSettings
from edge.fwlib.worker import HandleWorker

log = logging.getLogger(__name__)


@dataclass
class FwlibHost:
    """A running host; `await close()` stops serving, frees every handle and ends the library process."""

    library: FocasLibrary
    workers: dict[str, HandleWorker] = field(default_factory=dict)
    endpoints: dict[str, PackedEndpoint] = field(default_factory=dict)

    async def close(self) -> None:
        for endpoint in self.endpoints.values():
            await endpoint.close()
        for worker in self.workers.values():
            await worker.close()
        self.library.exit()


async def start_host(settings: HostSettings, library: FocasLibrary) -> FwlibHost:
    """Start the library process (Linux), then a worker and an endpoint per machine."""
    code = library.startup(settings.log_file)
    if code != 0:
        raise LibraryLoadError(f"{library.path}: cnc_startupprocess answered EW {code}")
    host = FwlibHost(library)
    try:
        for machine in settings.machines:
            worker = HandleWorker(library, machine.target(), settings.timeouts())
            host.workers[machine.name] = worker
            address = machine.address()
            endpoint = await start_packed_endpoint(
                worker.respond, address.host or "127.0.0.1", address.port,
                unix_path=address.path or None, unix_mode=settings.socket_mode, name=machine.name)
            host.endpoints[machine.name] = endpoint
            worker.start()
            log.info("library host serving machine=%s cnc=%s listen=%s", machine.name, machine.cnc,
                     endpoint.address)
    except BaseException:
        await host.close()
        raise
    return host
