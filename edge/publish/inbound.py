"""What the publisher hands up from the command topics (DCMD, `<prefix>/<machine>/cmd`): the source of a
command, so its reply can go back the same way, and the handlers the command layer installs.

The publisher only decodes and routes; parsing, policy and writing are edge.command's job.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from edge.publish.holding import Format


@dataclass(frozen=True, slots=True)
class CommandSource:
    """Where a command came from, so the reply (if any) can go back the same way."""

    format: Format
    topic: str
    response_topic: str | None = None  # MQTT 5 request/response
    correlation_data: bytes | None = None


DeviceCommandHandler = Callable[[str, str, object, CommandSource], Awaitable[None]]
JsonCommandHandler = Callable[[str, bytes, CommandSource], Awaitable[None]]
# A DCMD metric refused here (unknown device/metric, read-only, bad value): device, metric, code, reason.
RefusedCommandHandler = Callable[[str, str | None, str, str, CommandSource], None]


@dataclass
class CommandHandlers:
    """The command layer's handlers, installed after the publisher is built (None: commands are refused)."""

    device: DeviceCommandHandler | None = None
    json: JsonCommandHandler | None = None
    refused: RefusedCommandHandler | None = None
