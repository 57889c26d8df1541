"""Remote writes arriving over MQTT (Sparkplug DCMD, JSON cmd topic): the daemon's entry point.

Placeholder seam: until the command layer is built every write is refused (writes are off by
default anyway). The daemon wires `on_device_command` / `on_json_command` to the publisher and calls
`reconfigure` on reload.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

from edge.config import Config

if TYPE_CHECKING:
    from edge.collect.poller import MachinePoller
    from edge.publish.publisher import CommandSource, Publisher

log = logging.getLogger(__name__)


class CommandService:
    def __init__(self, config: Config, publisher: Publisher, pollers: Mapping[str, MachinePoller]) -> None:
        self.config = config
        self.publisher = publisher
        self.pollers = pollers

    def reconfigure(self, config: Config) -> None:
        self.config = config

    async def on_device_command(self, device_id: str, metric: str, value: object, source: CommandSource) -> None:
        log.warning("write refused (not implemented) machine=%s metric=%s topic=%s", device_id, metric,
                    source.topic)

    async def on_json_command(self, device_id: str, payload: bytes, source: CommandSource) -> None:
        log.warning("write refused (not implemented) machine=%s topic=%s", device_id, source.topic)
        reply = {"id": None, "ok": False, "error": {"code": "not_supported", "message": "writes not available"}}
        await self.publisher.publish_json_reply(device_id, reply, source)

    async def close(self) -> None:
        """Stop accepting commands; pending writes finish or fail."""
