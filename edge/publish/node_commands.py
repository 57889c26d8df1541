"""Sparkplug commands for this edge node: NCMD/DCMD topics and payloads read into events.

A command is resolved against what the node declared (its NBIRTH and each device's DBIRTH: names, aliases,
types, writability); anything that cannot be acted on becomes a CommandIgnored with the reason, for the log,
the counters and the write audit. Kept apart from edge.publish.node, which builds the messages, so that file
holds one job: the session's outgoing side.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from edge.publish import payload as pl
from edge.publish.aliases import NODE, AliasMap
from edge.publish.device_table import DeviceTable
from edge.publish.sparkplug_b_pb2 import Payload
from edge.samples import MetricType

NAMESPACE = "spBv1.0"


@dataclass(frozen=True, slots=True)
class RebirthRequested:
    """An NCMD `Node Control/Rebirth` = true."""


@dataclass(frozen=True, slots=True)
class DeviceCommand:
    """A DCMD metric resolved against the device's DBIRTH and decoded to its declared type."""

    device_id: str
    metric_name: str
    value: object


@dataclass(frozen=True, slots=True)
class CommandIgnored:
    """A command metric that cannot be acted on; `reason` says why (for the log and counters)."""

    reason: str
    unknown: bool  # True: name/alias/device not known; False: known but rejected (read-only, bad value)
    # A refused DCMD metric, for the write audit: the device, the metric (name, or alias=N) and the write
    # reply code (edge.command.errors) that says why; None for anything that is not a DCMD metric.
    device_id: str | None = None
    metric: str | None = None
    code: str | None = None


CommandEvent = RebirthRequested | DeviceCommand | CommandIgnored


class CommandReader:
    """Reads the commands addressed to one edge node, against the node's current births."""

    def __init__(self, group_id: str, edge_node_id: str, aliases: AliasMap, node_table: Callable[[], DeviceTable],
                 devices: Mapping[str, DeviceTable]) -> None:
        self.group_id = group_id
        self.edge_node_id = edge_node_id
        self._aliases = aliases
        self._node_table = node_table  # the node's own metrics (NBIRTH); replaced as node metrics are added
        self._devices = devices

    def parse(self, topic: str, data: bytes) -> list[CommandEvent]:
        """NCMD/DCMD -> events; anything unusable becomes CommandIgnored with the reason."""
        parts = topic.split("/")
        mine = len(parts) >= 4 and parts[0] == NAMESPACE and parts[1] == self.group_id
        if not mine or parts[3] != self.edge_node_id:
            return [CommandIgnored(f"topic {topic!r} is not a command for this node", unknown=True)]
        try:
            p = pl.decode(data)
        except ValueError as exc:
            device = parts[4] if parts[2] == "DCMD" and len(parts) == 5 else None
            return [CommandIgnored(f"{topic}: {exc}", unknown=False, device_id=device, code="malformed")]
        if parts[2] == "NCMD" and len(parts) == 4:
            return [self._node_command(m) for m in p.metrics]
        if parts[2] == "DCMD" and len(parts) == 5:
            if not p.metrics:  # still a command someone sent: refused and audited, not dropped unseen
                return [CommandIgnored(f"{topic}: a DCMD without metrics", unknown=False, device_id=parts[4],
                                       code="malformed")]
            return [self._device_command(parts[4], m) for m in p.metrics]
        expected = "expected NCMD/<edge> or DCMD/<edge>/<device>"
        return [CommandIgnored(f"topic {topic!r}: {expected}", unknown=True)]

    def _resolve(self, device_key: str, m: Payload.Metric) -> str | None:
        if m.HasField("name") and m.name:
            return m.name
        if m.HasField("alias"):
            found = self._aliases.resolve(m.alias)
            if found is not None and found[0] == device_key:
                return found[1]
        return None

    def _node_command(self, m: Payload.Metric) -> CommandEvent:
        name = self._resolve(NODE, m)
        if name == pl.REBIRTH_METRIC:
            try:
                value = pl.get_value(m, MetricType.BOOLEAN)
            except ValueError as exc:
                return CommandIgnored(f"NCMD {name}: {exc}", unknown=False)
            if value:
                return RebirthRequested()
            return CommandIgnored(f"NCMD {name}: value false, nothing to do", unknown=False)
        if name is None:
            return CommandIgnored(f"NCMD metric {_describe(m)}: expected a known name or alias", unknown=True)
        known = name in self._node_table().layout.specs
        return CommandIgnored(f"NCMD {name}: node metric is not writable", unknown=not known)

    def _device_command(self, device_id: str, m: Payload.Metric) -> CommandEvent:
        dev = self._devices.get(device_id)
        described = m.name if m.HasField("name") and m.name else _describe(m)
        if dev is None:
            return CommandIgnored(f"DCMD for unknown device {device_id!r}", unknown=True, device_id=device_id,
                                  metric=described, code="unknown_machine")
        name = self._resolve(device_id, m)
        spec = dev.layout.specs.get(name) if name is not None else None
        if name is None or spec is None:
            return CommandIgnored(f"DCMD {device_id}: metric {_describe(m)} not in its DBIRTH", unknown=True,
                                  device_id=device_id, metric=described, code="unknown_metric")
        if not spec.writable:
            return CommandIgnored(f"DCMD {device_id}: metric {name!r} is read-only", unknown=False,
                                  device_id=device_id, metric=name, code="invalid_target")
        try:
            value = pl.get_value(m, spec.type)
        except ValueError as exc:
            return CommandIgnored(f"DCMD {device_id} {name}: {exc}", unknown=False, device_id=device_id,
                                  metric=name, code="wrong_type")
        return DeviceCommand(device_id, name, value)


def _describe(m: Payload.Metric) -> str:
    if m.HasField("name"):
        return f"name={m.name!r}"
    return f"alias={m.alias}" if m.HasField("alias") else "without name or alias"
