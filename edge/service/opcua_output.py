"""The daemon's OPC UA output: the server (edge.opcua) with its writes bound to the command layer.

edge.opcua knows nothing of edge.command: this module hands it a MetricWriter that turns a client's write
into `CommandService.write_metrics` (policy, bounds, queue, read-back, audit: the path JSON and DCMD
take) and answers the outcome, and a check of which metric nodes the write policy covers. asyncua is
imported only here, and only when the section is enabled.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from edge.publish import CommandSource

if TYPE_CHECKING:
    from edge.command import CommandService
    from edge.opcua.output import OpcUaOutput
    from edge.opcua.server import MetricWrite
    from edge.opcua.settings import OpcUaSettings
    from edge.opcua.writes import WriteOutcome

log = logging.getLogger(__name__)


def opcua_output(settings: OpcUaSettings | None, commands: CommandService) -> OpcUaOutput | None:
    """The OPC UA output (not started), or None when the section is off or the extra is missing."""
    if settings is None:
        return None
    from edge.opcua import missing_extra

    missing = missing_extra()
    if missing is not None:
        log.error("opcua.enabled is true but %s; running without the OPC UA server", missing)
        return None
    from edge.opcua.output import OpcUaOutput

    logging.getLogger("asyncua").setLevel(max(logging.WARNING, logging.getLogger("asyncua").getEffectiveLevel()))
    return OpcUaOutput(settings, CommandWriter(commands), commands.writable_metrics)


class CommandWriter:
    """A client's write of a metric node, carried out by the command layer; its outcome for the status."""

    def __init__(self, commands: CommandService) -> None:
        self.commands = commands

    async def __call__(self, request: MetricWrite) -> WriteOutcome:
        from edge.opcua.writes import WriteOutcome

        source = CommandSource("opcua", request.node)
        if request.refusal is not None:
            code, reason = request.refusal
            self.commands.refuse_metric(request.device_id, request.metric, code, reason, source, request.client)
            return WriteOutcome(False, code, reason)
        (result,) = await self.commands.write_metrics(request.device_id, [(request.metric, request.value)], source,
                                                      request.client)
        return WriteOutcome(result.ok, None if result.ok else str(result.code), result.message)
