"""The file's top level: Config holds every section (mqtt, machines, alarms, writes, http, spool, opcua,
state_dir, poll_grid_s) and answers the questions that span sections: the devices of multi-path machines, a
machine's alarms and effective write policy, the poll grid in use, and in a fleet file with `gateways:` which
gateway this config is for and which machines the others poll.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pydantic import ByteSize, Field, PrivateAttr, field_validator, model_validator

from edge.config.fields import Duration, HostName, _Model
from edge.config.machines import AlarmsConfig, MachineConfig
from edge.config.mqtt import MqttConfig
from edge.config.opcua import OpcUaConfig
from edge.config.poll import AUTO_POLL_GRID_CAP_S, PollGrid
from edge.config.sharing import share_equal_parts
from edge.config.writes import MachineWrites, WritePolicy, WritesConfig

DEFAULT_STATE_DIR = Path("/var/lib/focas-edge")


class HttpConfig(_Model):
    enabled: bool = False
    host: HostName = "127.0.0.1"
    port: int = Field(default=9108, ge=1, le=65535)
    healthy_share: float = Field(default=0.5, ge=0.0, le=1.0)


class SpoolConfig(_Model):
    max_bytes: ByteSize = Field(default=ByteSize(256 * 1024 * 1024), ge=1024 * 1024)
    max_age_s: Duration = 7 * 24 * 3600.0


class Config(_Model):
    mqtt: MqttConfig
    machines: list[MachineConfig] = Field(min_length=1)
    alarms: AlarmsConfig = Field(default_factory=AlarmsConfig)
    writes: WritesConfig = Field(default_factory=WritesConfig)
    state_dir: Path | None = None
    http: HttpConfig = Field(default_factory=HttpConfig)
    spool: SpoolConfig = Field(default_factory=SpoolConfig)
    opcua: OpcUaConfig = Field(default_factory=OpcUaConfig)
    # Poll wake-ups are rounded up to this grid, so the machines due in one slot share one event-loop turn
    # (docs/performance.md): a poll is at most this much later than due, never earlier, never skipped.
    # None is `auto` (the default): see poll_grid_step_s.
    poll_grid_s: PollGrid = None

    _warnings: list[str] = PrivateAttr(default_factory=list)
    _state_dir: Path = PrivateAttr(default=DEFAULT_STATE_DIR)
    _gateway: str | None = PrivateAttr(default=None)
    _fleet: dict[str, list[str]] = PrivateAttr(default_factory=dict)

    @field_validator("machines")
    @classmethod
    def _unique_ids(cls, machines: list[MachineConfig]) -> list[MachineConfig]:
        for problem in _duplicate_ids({"machines": [{"id": m.id} for m in machines]}):
            raise ValueError("@" + problem.removeprefix("machines").replace(": ", "@", 1))
        ids = {m.id.lower(): m.id for m in machines}
        for machine in machines:
            for device in machine.path_devices()[1:]:
                if device.id.lower() in ids:
                    raise ValueError(f"machine {machine.id!r} polls {machine.paths} paths, so its path {device.path} "
                                     f"is the device {device.id!r}, already a machine id")
        return machines

    @field_validator("machines")
    @classmethod
    def _share_equal_parts(cls, machines: list[MachineConfig]) -> list[MachineConfig]:
        return share_equal_parts(machines)  # edge.config.sharing: one PollPlan for machines polling alike

    @model_validator(mode="after")
    def _grid_fits_every_period(self) -> Config:
        if self.poll_grid_s is None:
            return self  # auto fits by construction
        for machine in self.machines:
            fastest = machine.poll.periods.fastest_s
            if self.poll_grid_s > fastest / 2:
                raise ValueError(f"poll_grid_s {self.poll_grid_s:g}s is more than half of machine {machine.id!r}'s "
                                 f"fastest poll period ({fastest:g}s): lower poll_grid_s to {fastest / 2:g}s or less")
        return self

    @property
    def poll_grid_step_s(self) -> float:
        """The grid in use: the configured one, or (auto) half the fleet's fastest period capped at 50 ms.

        Coarser is cheaper (more machines share a loop turn, docs/performance.md); a poll is at most one
        step late, and polls stay evenly spaced where the period is a multiple of the step. Half a period
        keeps every fleet spread over at least two slots of a period.
        """
        if self.poll_grid_s is not None:
            return self.poll_grid_s
        return min([AUTO_POLL_GRID_CAP_S, *(m.poll.periods.fastest_s / 2 for m in self.machines)])

    @property
    def warnings(self) -> list[str]:
        return list(self._warnings)

    @property
    def gateway(self) -> str | None:
        """The gateway this config is for, in a fleet file with `gateways:` (None: the file is one gateway's)."""
        return self._gateway

    @property
    def fleet(self) -> dict[str, list[str]]:
        """Every gateway of the fleet file and the machine ids it polls ({} without `gateways:`)."""
        return {name: list(ids) for name, ids in self._fleet.items()}

    def only_gateway(self, gateway: str, fleet: dict[str, list[str]]) -> Config:
        """This config as `gateway` runs it: its own machines only (possibly none, while they are moved)."""
        config = self.model_copy(update={"machines": [m for m in self.machines if m.gateway == gateway]})
        config._warnings = list(self._warnings)
        config._gateway = gateway
        config._fleet = {name: list(ids) for name, ids in fleet.items()}
        if not config.machines:
            config._warnings.append(f"gateway {gateway!r} polls no machine: no machine in the file names it")
        return config

    @property
    def resolved_state_dir(self) -> Path:
        """state_dir from the file, else $STATE_DIRECTORY (systemd), else /var/lib/focas-edge."""
        return self.state_dir if self.state_dir is not None else self._state_dir

    def devices(self) -> list[MachineConfig]:
        """Every polled device: each machine, and for a multi-path machine one entry per further path."""
        return [device for machine in self.machines for device in machine.path_devices()]

    def machine(self, machine_id: str) -> MachineConfig:
        for machine in self.devices():
            if machine.id == machine_id:
                return machine
        raise KeyError(machine_id)

    def alarms_for(self, machine: MachineConfig) -> AlarmsConfig:
        return machine.alarms if machine.alarms is not None else self.alarms

    def write_policy(self, machine: MachineConfig) -> WritePolicy:
        own = machine.writes or MachineWrites()
        return WritePolicy(
            enabled=self.writes.enabled and own.enabled is not False,
            allow=tuple(self.writes.allow) + tuple(own.allow),
            rate_limit=own.rate_limit or self.writes.rate_limit,
            reconnect_deadline_s=self.writes.reconnect_deadline_s,
            max_payload_bytes=self.writes.max_payload_bytes,
        )


def _duplicate_ids(data: dict[str, Any]) -> Iterator[str]:
    """Machine ids used twice (ignoring case), read from the raw data so they show beside other errors."""
    machines = data.get("machines")
    seen: dict[str, int] = {}
    for index, machine in enumerate(machines if isinstance(machines, list) else []):
        machine_id = machine.get("id") if isinstance(machine, dict) else None
        if not isinstance(machine_id, str):
            continue
        first = seen.get(machine_id.lower())
        if first is not None:
            yield (f"machines[{index}].id: {machine_id!r} is already the id of machines[{first}]"
                   " (device ids are unique per edge node, ignoring case)")
        else:
            seen[machine_id.lower()] = index
