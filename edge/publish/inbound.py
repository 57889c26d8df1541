"""What the publisher hands up from the command topics (DCMD, `<prefix>/<machine>/cmd`): the source of a
command, so its reply can go back the same way, and the handlers the command layer installs.

The publisher only decodes and routes; parsing, policy and writing are edge.command's job. A DCMD is handed
up whole (its decoded metrics and the ones it could not decode, with why), so the command layer can treat
one message as one command: capped, all-or-nothing, and audited once when refused.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Literal

from edge.publish.holding import Format


@dataclass(frozen=True, slots=True)
class CommandSource:
    """Where a command came from, so the reply (if any) can go back the same way."""

    format: Format | Literal["opcua"]  # an OPC UA write has no reply topic: its Write response answers it
    topic: str
    response_topic: str | None = None  # MQTT 5 request/response
    correlation_data: bytes | None = None


@dataclass(frozen=True, slots=True)
class RefusedMetric:
    """A DCMD metric the publisher could not turn into a write: the metric (name, `alias=N`, or None for a
    payload that did not decode), the write reply code (edge.command.errors) and the reason."""

    metric: str | None
    code: str
    reason: str


@dataclass(frozen=True, slots=True)
class DeviceCommands:
    """One DCMD message for one device: the metrics resolved against its DBIRTH and decoded to their birth
    type (in message order), the metrics refused, and the payload's size (the command layer caps it)."""

    device_id: str
    writes: tuple[tuple[str, object], ...]
    refused: tuple[RefusedMetric, ...]
    payload_bytes: int

    @property
    def metric_count(self) -> int:
        return len(self.writes) + len(self.refused)


DeviceCommandHandler = Callable[[DeviceCommands, CommandSource], Awaitable[None]]
JsonCommandHandler = Callable[[str, bytes, CommandSource], Awaitable[None]]


@dataclass
class CommandHandlers:
    """The command layer's handlers, installed after the publisher is built (None: commands are refused)."""

    device: DeviceCommandHandler | None = None
    json: JsonCommandHandler | None = None
