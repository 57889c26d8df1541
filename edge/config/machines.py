"""`machines:` one CNC each: its endpoint, time zone, timeouts, CNC paths, poll plan, and its own alarms
and writes settings (AlarmsConfig is also the global `alarms:` section).

The endpoint is the native host/port (transport focas), or a packed address (tcp:HOST:PORT or
unix:/PATH), with an optional FOCAS library host beside the native one. `_endpoint_rules` states the
rules between those keys once, for the model validator and for load's re-check on the raw data.
"""

from __future__ import annotations

import re
from typing import Literal
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from pydantic import Field, field_validator, model_validator

from edge.config.fields import Duration, HostName, SparkplugId, _at, _Model, check_host
from edge.config.poll import PollPlan
from edge.config.writes import MachineWrites
from edge.focas.paths import MAX_PATHS

HISTORY_DEPTH_MIN = 1
HISTORY_DEPTH_MAX = 250
NATIVE_PORT = 8193


class AlarmsConfig(_Model):
    mode: Literal["ActiveOnly", "ActivePlusHistory"] = "ActiveOnly"
    history_interval: Duration = 300.0
    history_depth: int = 100

    @field_validator("history_depth")
    @classmethod
    def _clamp(cls, value: int) -> int:
        return min(max(value, HISTORY_DEPTH_MIN), HISTORY_DEPTH_MAX)


class Timeouts(_Model):
    connect_s: Duration = 5.0
    request_s: Duration = 5.0
    backoff_initial_s: Duration = 0.5
    backoff_max_s: Duration = 30.0


_PACKED_ADDRESS_RE = re.compile(r"tcp:[^:\s]+:\d{1,5}|unix:/\S+", re.ASCII)


class MachineConfig(_Model):
    id: SparkplugId
    host: HostName | None = None
    port: int = Field(default=NATIVE_PORT, ge=1, le=65535)
    transport: Literal["focas", "packed"] = "focas"
    address: str | None = None
    # A FOCAS library host (focas-edge fwlib-host) beside the native connection: alarm history and parameter
    # writes go there, every other function stays native (edge.focas.routed).
    fwlib_host: str | None = None
    series: str | None = None
    timezone: str = "UTC"
    timeouts: Timeouts = Field(default_factory=Timeouts)
    # Subpackets per request PDU (focas only). No public source states a control's limit; 32 is safe.
    max_subpackets: int | None = Field(default=None, ge=2, le=128)
    max_skew_s: Duration = 60.0
    poll: PollPlan = Field(default_factory=PollPlan)
    alarms: AlarmsConfig | None = None
    writes: MachineWrites | None = None
    # CNC paths to poll (a twin-turret lathe has 2): path 1 is this machine's device, path n the device
    # `<id>-path<n>` (see path_devices). `path` is the one this entry's session reads.
    paths: int = Field(default=1, ge=1, le=MAX_PATHS)
    path: int = Field(default=1, ge=1, le=MAX_PATHS)
    # The gateway that polls this machine, in a fleet file with `gateways:` (edge.config.gateways).
    gateway: str | None = None

    def path_devices(self) -> list[MachineConfig]:
        """This machine, then one entry per further path: same settings, id `<id>-path<n>`, path n."""
        others = [self.model_copy(update={"id": f"{self.id}-path{n}", "path": n, "paths": 1})
                  for n in range(2, self.paths + 1)]
        return [self, *others]

    @field_validator("timezone")
    @classmethod
    def _zone(cls, value: str) -> str:
        try:
            ZoneInfo(value)
        except (ZoneInfoNotFoundError, ValueError):
            raise ValueError(f"unknown IANA time zone {value!r} (e.g. UTC, Europe/Berlin, America/Chicago)") \
                from None
        return value

    @field_validator("address", "fwlib_host")
    @classmethod
    def _address(cls, value: str | None) -> str | None:
        if value is not None and not _PACKED_ADDRESS_RE.fullmatch(value):
            raise ValueError(f"expected tcp:HOST:PORT or unix:/PATH, got {value!r}")
        if value is not None and value.startswith("tcp:"):
            check_host(value.removeprefix("tcp:").rpartition(":")[0])
        return value

    @model_validator(mode="after")
    def _endpoint(self) -> MachineConfig:
        for key, message in _endpoint_rules(self.transport, self.host, self.address, self.max_subpackets,
                                            self.fwlib_host, self.paths):
            raise _at(key, message)
        return self

    @property
    def zone(self) -> ZoneInfo:
        return ZoneInfo(self.timezone)

    @property
    def endpoint(self) -> str:
        """The address open_session takes: host:port (focas), tcp:host:port or unix:/path (packed)."""
        if self.address is not None:
            return self.address
        if self.transport == "packed":
            return f"tcp:{self.host}:{self.port}"
        return f"{self.host}:{self.port}"


def _endpoint_rules(transport: object, host: object, address: object,
                    max_subpackets: object, fwlib_host: object, paths: object = 1) -> list[tuple[str, str]]:
    """Rules between a machine's endpoint keys as (key, message), for the model and the raw re-check."""
    rules = []
    if transport == "focas" and address is not None:
        rules.append(("address", "only for transport packed; the focas transport uses host and port"))
    if host is None and address is None:
        rules.append(("host", "required" + (" (or address)" if transport == "packed" else "")))
    if host is not None and address is not None:
        rules.append(("address", "give host/port or address, not both"))
    if transport != "focas" and fwlib_host is not None:
        rules.append(("fwlib_host", "only beside the native transport (focas); with transport packed, address "
                                    "already names the library host"))
    if transport != "focas" and paths not in (1, None):
        rules.append(("paths", "only for transport focas (the packed surface reads path 1)"))
    if transport != "focas" and max_subpackets is not None:
        rules.append(("max_subpackets", "only for transport focas (the packed surface has no subpackets)"))
    return rules
