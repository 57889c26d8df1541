"""The config turned into the settings of the layers the service wires together: the one place the pydantic
config models are read on behalf of collect, command and publish, so those layers take plain frozen values and
never import edge.config. Values only: every decision (what to poll, whether a write may pass) stays in its layer.
"""

from __future__ import annotations

from edge.collect import (
    MachineSettings,
    MacroValues,
    NumberedValue,
    Periods,
    PmcValues,
    PollSettings,
    Timeouts,
)
from edge.command import AllowRule, CommandSettings, RateLimit, WritePolicy
from edge.config import AlarmsConfig, Config, MachineConfig, PollPlan
from edge.config.mqtt import gateway_name
from edge.opcua.settings import OpcUaSettings
from edge.publish.settings import PublishSettings


def publish_settings(config: Config) -> PublishSettings:
    """The publisher's view of the config (secrets read here, at start, never logged)."""
    mqtt = config.mqtt
    tls = mqtt.tls
    spb = mqtt.sparkplug
    settings = PublishSettings(
        host=mqtt.host,
        port=mqtt.effective_port,
        tls=tls is not None,
        tls_ca_file=tls.ca_file if tls else None,
        tls_cert_file=tls.cert_file if tls else None,
        tls_key_file=tls.key_file if tls else None,
        tls_insecure=tls.insecure_skip_verify if tls else False,
        username=mqtt.username,
        password=mqtt.read_password(),
        protocol=mqtt.protocol,
        keepalive=mqtt.keepalive,
        formats=frozenset(mqtt.formats),
        json_prefix=mqtt.json_prefix,
        state_dir=config.resolved_state_dir,
    )
    if mqtt.client_id:
        settings.client_id = mqtt.client_id
    elif spb is not None:
        settings.client_id = f"focas-edge-{spb.group_id}-{spb.edge_node_id}"
    else:  # JSON only: two gateways must not share a client id (the broker would take turns kicking them)
        settings.client_id = f"focas-edge-{gateway_name()}"
    if spb is not None:
        settings.group_id = spb.group_id
        settings.edge_node_id = spb.edge_node_id
        settings.primary_host_id = spb.primary_host_id
    return settings


def machine_settings(config: Config, machine: MachineConfig) -> MachineSettings:
    """The collector's view of one device of the config (a machine, or one further path of one)."""
    if any(m is machine for m in config.machines):  # a machine itself, not one of its further paths: its own
        control = machine  # control (asking every machine for its paths, for every machine, took 4 s at 1,000)
    else:
        control = next((m for m in config.machines if any(d.id == machine.id for d in m.path_devices())), machine)
    return _machine_settings(config, machine, tuple(d.id for d in control.path_devices()))


def _machine_settings(config: Config, machine: MachineConfig, path_devices: tuple[str, ...]) -> MachineSettings:
    timeouts = machine.timeouts
    return MachineSettings(
        id=machine.id,
        transport=machine.transport,
        endpoint=machine.endpoint,
        fwlib_host=machine.fwlib_host,
        max_subpackets=machine.max_subpackets,
        timeouts=Timeouts(timeouts.connect_s, timeouts.request_s, timeouts.backoff_initial_s, timeouts.backoff_max_s),
        zone=machine.zone,
        max_skew_s=machine.max_skew_s,
        path=machine.path,
        path_devices=path_devices,
        poll=shared_poll(poll_settings(machine.poll, config.alarms_for(machine))),
        series=machine.series,
    )


_POLLS: dict[PollSettings, PollSettings] = {}


def shared_poll(poll: PollSettings) -> PollSettings:
    """One object for equal poll settings: a fleet's machines mostly poll alike, and the metric names these
    settings carry (and the plans built from them, edge.collect.plan) are then held once, not per machine."""
    if len(_POLLS) >= 256:
        _POLLS.clear()
    return _POLLS.setdefault(poll, poll)


def poll_settings(poll: PollPlan, alarms: AlarmsConfig) -> PollSettings:
    """A machine's `poll` section and alarm mode, with metric names and PMC targets resolved."""
    periods = poll.periods
    return PollSettings(
        periods=Periods(status=periods.status, macros=periods.macros, pmc=periods.pmc, params=periods.params,
                        diags=periods.diags, loads=periods.loads, counters=periods.counters,
                        alarm_history=alarms.history_interval),
        positions=tuple(poll.positions),
        part_count=poll.part_count,
        program_name=poll.program_name,
        operator_messages=poll.operator_messages,
        servo_load=poll.servo_load,
        timers=poll.timers,
        tool_offsets=poll.tool_offsets,
        work_offsets=tuple(poll.work_offsets),
        modal=poll.modal,
        tool_number=poll.tool_number,
        macros=tuple(MacroValues(m.numbers.start, m.numbers.stop - 1, tuple(m.metric_name(n) for n in m.numbers),
                                 m.deadband) for m in poll.macros),
        pmc=tuple(PmcValues(p.target, p.bits, tuple(p.metric_names()), p.deadband) for p in poll.pmc),
        params=tuple(NumberedValue(p.number, p.axis, p.metric_name("Param"), p.deadband) for p in poll.params),
        diags=tuple(NumberedValue(d.number, d.axis, d.metric_name("Diag"), d.deadband) for d in poll.diags),
        alarm_history=alarms.mode == "ActivePlusHistory",
        alarm_history_depth=alarms.history_depth,
        retry_dropped=poll.retry_dropped,
    )


def command_settings(config: Config) -> CommandSettings:
    """The write path's view of the config: every device with its effective write policy."""
    machines: dict[str, MachineSettings] = {}
    policies: dict[str, WritePolicy] = {}
    for control in config.machines:
        devices = control.path_devices()
        ids = tuple(d.id for d in devices)
        for device in devices:
            machines[device.id] = _machine_settings(config, device, ids)
            policies[device.id] = write_policy(config, device)
    audit = config.writes.audit
    return CommandSettings(state_dir=config.resolved_state_dir, max_payload_bytes=config.writes.max_payload_bytes,
                           machines=machines, policies=policies, audit_max_bytes=int(audit.max_bytes),
                           audit_keep=audit.keep)


def write_policy(config: Config, machine: MachineConfig) -> WritePolicy:
    """The machine's effective write policy (config.write_policy), as the command layer's plain values."""
    policy = config.write_policy(machine)
    return WritePolicy(
        enabled=policy.enabled,
        allow=tuple(AllowRule(rule.target, rule.min, rule.max) for rule in policy.allow),
        rate_limit=RateLimit(policy.rate_limit.max_writes, policy.rate_limit.per_s),
        reconnect_deadline_s=policy.reconnect_deadline_s,
    )


def opcua_settings(config: Config) -> OpcUaSettings | None:
    """The OPC UA server's settings with its users' passwords read (at start, never logged); None when the
    `opcua:` section is off."""
    section = config.opcua
    if not section.enabled:
        return None
    spb = config.mqtt.sparkplug
    node = f"{spb.group_id}:{spb.edge_node_id}" if spb is not None else "gateway"
    return OpcUaSettings(
        state_dir=config.resolved_state_dir, host=section.host, port=section.port, path=section.path,
        security=tuple(section.security), allow_anonymous=section.allow_anonymous, users=section.read_users(),
        certificate_file=section.certificate_file, private_key_file=section.private_key_file,
        application_uri=f"urn:focas-edge:{node}", threaded=section.threaded,
        write_timeout_s=section.write_timeout_s, max_sessions=section.max_sessions)
