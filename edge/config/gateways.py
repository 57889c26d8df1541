"""`gateways:` one fleet file for many gateways, each polling only the machines that name it.

A plant that outgrows one box splits its fleet between gateways but keeps one file, so a machine's settings
never exist twice and moving it is a one-word edit (`gateway: hall-b`). The file lists the gateways by name;
each entry may override the top-level sections that differ per box (GATEWAY_SECTIONS: its broker, state_dir,
ports), merged key by key as `defaults:` are. A gateway's Sparkplug edge node id is its name unless its entry
(not the shared top level) sets one: two gateways with one edge node id would kill each other's sessions on
the broker, so ids and explicit client ids that collide are refused.

Which gateway a process is comes from outside the shared file: `--gateway NAME` or FOCAS_EDGE_GATEWAY.
Without a `gateways:` section nothing here applies and the file is one gateway's, as before.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from edge.config.fields import check_sparkplug_id
from edge.config.merge import deep_merge

GATEWAYS_KEY = "gateways"
GATEWAY_KEY = "gateway"
GATEWAY_ENV = "FOCAS_EDGE_GATEWAY"
# The top-level sections a gateway's entry may override: what differs between boxes, not what they poll.
GATEWAY_SECTIONS = ("mqtt", "state_dir", "http", "spool", "opcua", "poll_grid_s")


@dataclass
class FleetPlan:
    """The `gateways:` section read from the raw data: the names, each one's overrides, who polls what."""

    bodies: dict[str, dict[str, Any]] = field(default_factory=dict)
    owner: dict[str, str] = field(default_factory=dict)  # machine id -> gateway name, in file order
    problems: list[str] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return list(self.bodies)

    def defined(self) -> str:
        return ", ".join(self.bodies) or "none"

    def machines_of(self, gateway: str) -> list[str]:
        return [machine for machine, owner in self.owner.items() if owner == gateway]

    def data_for(self, data: dict[str, Any], gateway: str) -> dict[str, Any]:
        """The config data as `gateway` sees it: its overrides merged over the shared sections, its edge node
        id defaulted to its name. Every machine stays in, so the whole fleet is validated on every box."""
        body = self.bodies[gateway]
        merged = {key: value for key, value in data.items() if key != GATEWAYS_KEY}
        for key, value in body.items():
            below = merged.get(key)
            merged[key] = deep_merge(below, value) if isinstance(below, dict) and isinstance(value, dict) else value
        mqtt = merged.get("mqtt")
        sparkplug = mqtt.get("sparkplug") if isinstance(mqtt, dict) else None
        if isinstance(sparkplug, dict) and "edge_node_id" not in sparkplug:
            merged["mqtt"] = {**mqtt, "sparkplug": {**sparkplug, "edge_node_id": gateway}}  # type: ignore[dict-item]
        return merged

    def rename(self, problem: str, gateway: str) -> str:
        """A problem found in gateway's merged data, named where its entry sets the key (so its line is found):
        `mqtt.port` becomes `gateways.hall-a.mqtt.port` when hall-a's entry gives mqtt.port."""
        path, sep, message = problem.partition(": ")
        body: object = self.bodies.get(gateway, {})
        for part in path.split(".")[:2]:
            if not isinstance(body, dict) or part not in body:
                return problem
            body = body[part]
        return f"{GATEWAYS_KEY}.{gateway}.{path}{sep}{message}"


def read_plan(data: dict[str, Any]) -> FleetPlan | None:
    """The fleet plan of a file with `gateways:`, its problems included; None for a one-gateway file (then a
    machine naming a gateway is a problem, reported by plain_file_problems)."""
    if GATEWAYS_KEY not in data:
        return None
    plan = FleetPlan()
    raw = data[GATEWAYS_KEY]
    if not isinstance(raw, dict) or not raw:
        plan.problems.append(f"{GATEWAYS_KEY}: expected a mapping of gateway names to their overrides "
                             f"(hall-a: {{mqtt: {{host: broker-a}}}}), got {_kind(raw)}")
        return plan
    for name, body in raw.items():
        _read_gateway(plan, str(name), body)
    machines = data.get("machines")
    for index, machine in enumerate(machines if isinstance(machines, list) else []):
        if isinstance(machine, dict):
            _read_assignment(plan, index, machine)
    plan.problems.extend(_identity_collisions(plan, data))
    return plan


def plain_file_problems(data: dict[str, Any], gateway: str | None) -> list[str]:
    """In a file without `gateways:`, a machine's `gateway:` and a chosen gateway have nothing to refer to."""
    problems = []
    if gateway is not None:
        problems.append(f"{GATEWAY_KEY} {gateway!r} was asked for (--gateway or {GATEWAY_ENV}), but the file "
                        f"has no {GATEWAYS_KEY}: section; drop the option or add the section (docs/config.md)")
    machines = data.get("machines")
    for index, machine in enumerate(machines if isinstance(machines, list) else []):
        if isinstance(machine, dict) and GATEWAY_KEY in machine:
            problems.append(f"machines[{index}].{GATEWAY_KEY}: names gateway {machine[GATEWAY_KEY]!r} but the "
                            f"file has no {GATEWAYS_KEY}: section listing the gateways")
    return problems


def _read_gateway(plan: FleetPlan, name: str, body: object) -> None:
    try:
        check_sparkplug_id(name)
    except ValueError as exc:
        plan.problems.append(f"{GATEWAYS_KEY}.{name}: the name is its default Sparkplug edge node id: {exc}")
    if body is None:
        body = {}
    if not isinstance(body, dict):
        plan.problems.append(f"{GATEWAYS_KEY}.{name}: expected a mapping of the sections it overrides "
                             f"({', '.join(GATEWAY_SECTIONS)}) or {{}}, got {_kind(body)}")
        body = {}
    for key in body:
        if key not in GATEWAY_SECTIONS:
            plan.problems.append(f"{GATEWAYS_KEY}.{name}.{key}: not a section a gateway may override "
                                 f"(expected one of: {', '.join(GATEWAY_SECTIONS)}); machines name their gateway "
                                 f"with {GATEWAY_KEY}: instead")
    plan.bodies[name] = {key: value for key, value in body.items() if key in GATEWAY_SECTIONS}


def _read_assignment(plan: FleetPlan, index: int, machine: dict[str, Any]) -> None:
    label = f"machines[{index}]" + (f" ({machine['id']})" if isinstance(machine.get("id"), str) else "")
    owner = machine.get(GATEWAY_KEY)
    if owner is None:
        plan.problems.append(f"machines[{index}].{GATEWAY_KEY}: required: the file lists gateways "
                             f"({plan.defined()}), so {label} must name the one that polls it")
    elif str(owner) not in plan.bodies:
        plan.problems.append(f"machines[{index}].{GATEWAY_KEY}: unknown gateway {owner!r} "
                             f"(defined in {GATEWAYS_KEY}: {plan.defined()})")
    elif isinstance(machine.get("id"), str):
        plan.owner[machine["id"]] = str(owner)


def _identity_collisions(plan: FleetPlan, data: dict[str, Any]) -> list[str]:
    """Two gateways with one Sparkplug edge node id, one explicit MQTT client id or one explicit JSON prefix: the
    broker would take one session over with the other, a host would read both boxes' machines as one node's,
    and one gateway's retained JSON status would overwrite the other's."""
    problems = []
    seen_node: dict[tuple[object, object], str] = {}
    seen_client: dict[object, str] = {}
    seen_prefix: dict[object, str] = {}
    for name in plan.names:
        mqtt = plan.data_for(data, name).get("mqtt")
        if not isinstance(mqtt, dict):
            continue
        sparkplug = mqtt.get("sparkplug")
        if isinstance(sparkplug, dict):
            node = (sparkplug.get("group_id"), sparkplug.get("edge_node_id"))
            if node in seen_node:
                problems.append(f"{GATEWAYS_KEY}.{name}: Sparkplug edge node id {node[1]!r} is also gateway "
                                f"{seen_node[node]!r}'s; each gateway needs its own (leave edge_node_id out of "
                                f"the shared mqtt.sparkplug so it defaults to the gateway's name, or set "
                                f"{GATEWAYS_KEY}.{name}.mqtt.sparkplug.edge_node_id)")
            else:
                seen_node[node] = name
        client = mqtt.get("client_id")
        if client is not None:
            if client in seen_client:
                problems.append(f"{GATEWAYS_KEY}.{name}: MQTT client id {client!r} is also gateway "
                                f"{seen_client[client]!r}'s; set it per gateway or leave it to the daemon")
            else:
                seen_client[client] = name
        json, formats = mqtt.get("json"), mqtt.get("formats")
        uses_json = not isinstance(formats, list) or "json" in formats
        prefix = json.get("prefix") if isinstance(json, dict) and uses_json else None
        if prefix is not None:
            if prefix in seen_prefix:
                problems.append(f"{GATEWAYS_KEY}.{name}: JSON prefix {prefix!r} is also gateway "
                                f"{seen_prefix[prefix]!r}'s; each gateway's retained <prefix>/_gateway/online "
                                f"would overwrite the other's: set it per gateway or leave it to the default")
            else:
                seen_prefix[prefix] = name
    return problems


def _kind(value: object) -> str:
    return "nothing" if value is None else type(value).__name__
