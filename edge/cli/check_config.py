"""`focas-edge check-config FILE`: validate a config file without connecting to anything.

Exit 0 with a short summary of what the daemon would do; exit 2 with every problem listed, each with
its path in the file. Warnings (values that were adjusted) are printed either way. Whatever `run` refuses
at start (state_dir, its files and its lock, the http port, the password), this refuses first with the
same line, because both ask the same functions.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from edge import ConfigError
from edge.cli import EXIT_OK, EXIT_USAGE
from edge.config import GATEWAY_ENV, Config, listen_port, load_config
from edge.config.service_access import (
    SERVICE_USER,
    current_account,
    service_problems,
    state_dir_problem,
    state_files_problem,
)
from edge.opcua import missing_extra
from edge.service.state_lock import held_message, holder


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "check-config", help="validate a config file without connecting",
        description="Validate a focas-edge YAML config: every problem is listed with its path in the file. "
                    "Whatever `run` would refuse, this refuses first, as the same user: secrets named by "
                    "password_env/password_file must be available, state_dir and the files in it writable, "
                    "state_dir not in use by another focas-edge, http.port free.",
        epilog="Exit codes: 0 valid, 2 invalid (every problem listed).")
    parser.add_argument("config", metavar="FILE", help="the YAML config file")
    parser.add_argument("--quiet", "-q", action="store_true", help="print nothing when the file is valid")
    parser.add_argument("--as-service", action="store_true",
                        help="check as the systemd service will run it: its user can read the config and every "
                             "file it names and write state_dir and the files in it (under the unit's "
                             "ProtectSystem=strict), the installed unit hands it the password (EnvironmentFile=, "
                             "LoadCredential=), and it may bind http.port; a running focas-edge.service holding "
                             "state_dir is then fine (a reload or restart of it)")
    parser.add_argument("--service-user", default=SERVICE_USER, metavar="NAME",
                        help=f"the service's user for --as-service (default {SERVICE_USER})")
    parser.add_argument("--gateway", default=os.environ.get(GATEWAY_ENV) or None, metavar="NAME",
                        help="in a fleet file with gateways:, check it as this gateway runs it (its overrides, "
                             "secrets, state_dir, ports) and list the machines it polls and those it leaves to "
                             f"the others (default ${GATEWAY_ENV}); without it, every gateway's view is validated "
                             "and the split is shown")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    notes: list[str] = []
    gateway = getattr(args, "gateway", None)  # a Namespace built by hand may lack it
    try:
        # As the service, the password is the unit's business (EnvironmentFile=, LoadCredential=), not this shell's.
        config = load_config(args.config, secrets=not args.as_service, gateway=gateway)
        if config.fleet and gateway is None:
            problems = []
            notes.append(f"a fleet file for {len(config.fleet)} gateways: give --gateway NAME (or {GATEWAY_ENV}) "
                         f"on a gateway's box to check what it runs there (secrets, state_dir, ports)")
        else:
            problems = usability_problems(config, Path(args.config),
                                          args.service_user if args.as_service else None, notes)
    except ConfigError as exc:
        problems = exc.problems
    if problems:
        print(f"{args.config}: invalid, {len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  {problem}", file=sys.stderr)
        return EXIT_USAGE
    for warning in config.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    if not args.quiet:
        print(summary(config, args.config) if not config.fleet or gateway else fleet_summary(config, args.config))
    return EXIT_OK


def usability_problems(config: Config, path: Path, service_user: str | None,
                       notes: list[str] | None = None) -> list[str]:
    """What `run` would refuse beyond the file itself, checked the way `run` checks it, as the user who
    runs check-config (or, with a service user, as the systemd service will run): state_dir and the files in
    it, the state_dir lock, the status HTTP port; with a service user also every file the config names
    and the password the unit hands over. `notes` receives what is fine but worth saying."""
    state_dir = config.resolved_state_dir
    problems: list[str | None] = []
    if service_user is None:
        problems.append(state_dir_problem(state_dir) or state_files_problem(current_account(), state_dir))
    else:
        problems.extend(service_problems(config, service_user, path))
    held = holder(state_dir)
    if held is not None and held.is_service and service_user is not None:
        if notes is not None:
            notes.append(f"state_dir {state_dir} is in use by the running {held.unit} (PID {held.pid}): fine for "
                         f"a reload or restart of it; its lock and http port are not checked again")
    elif held is not None:
        problems.append(held_message(state_dir, held))
    if config.http.enabled and held is None:
        problems.append(listen_port.probe(config.http.host, config.http.port))
    if config.opcua.enabled:
        missing = missing_extra()
        problems.append(f"opcua.enabled: {missing}" if missing is not None else None)
        if held is None:
            problems.append(listen_port.probe(config.opcua.host, config.opcua.port, "opcua"))
    return [p for p in problems if p is not None]


def summary(config: Config, source: str) -> str:
    mqtt = config.mqtt
    lines = [f"{source}: valid"]
    broker = f"{mqtt.host}:{mqtt.effective_port}{' (TLS)' if mqtt.tls else ''}, MQTT {mqtt.protocol}"
    lines.append(f"  broker     {broker}, formats {', '.join(mqtt.formats)}")
    if mqtt.sparkplug is not None:
        sp = mqtt.sparkplug
        host = f", primary host {sp.primary_host_id}" if sp.primary_host_id else ""
        lines.append(f"  sparkplug  spBv1.0/{sp.group_id}/+/{sp.edge_node_id}{host}")
    if "json" in mqtt.formats:
        lines.append(f"  json       {mqtt.json_prefix}/<machine>/...")
    if config.opcua.enabled:
        ua = config.opcua
        who = ", ".join([u.username for u in ua.users] + (["anonymous"] if ua.allow_anonymous else []))
        lines.append(f"  opcua      opc.tcp://{ua.host}:{ua.port}{ua.path}  security {', '.join(ua.security)}  "
                     f"users {who}")
    lines.append(f"  state_dir  {config.resolved_state_dir}")
    lines.append(f"  writes     {'enabled' if config.writes.enabled else 'disabled'}"
                 f" ({len(config.writes.allow)} global allow rule(s))")
    if config.gateway is not None:
        lines.extend(gateway_lines(config))
    lines.append(f"  machines   {len(config.machines)}")
    for machine in config.machines:
        poll = machine.poll
        alarms = config.alarms_for(machine)
        counts = (f"{sum(len(m.numbers) for m in poll.macros)} macros, "
                  f"{sum(len(p.addresses()) for p in poll.pmc)} PMC values, {len(poll.params)} params, "
                  f"{len(poll.diags)} diags")
        routed = f" + fwlib_host {machine.fwlib_host}" if machine.fwlib_host else ""
        paths = f"  {machine.paths} paths (devices {', '.join(d.id for d in machine.path_devices())})" \
            if machine.paths > 1 else ""
        lines.append(f"    {machine.id:<16} {machine.transport} {machine.endpoint}{routed}  tz {machine.timezone}  "
                     f"status every {poll.periods.status:g}s  {counts}  alarms {alarms.mode}{paths}")
    return "\n".join(lines)


def gateway_lines(config: Config) -> list[str]:
    """Which gateway this is, and the machines of the fleet file it leaves to the other gateways."""
    others = {name: ids for name, ids in config.fleet.items() if name != config.gateway}
    lines = [f"  gateway    {config.gateway} (of {', '.join(config.fleet)}): polls "
             f"{len(config.machines)} machine(s), leaves {sum(len(ids) for ids in others.values())} to the others"]
    lines += [f"    left to {name:<10} {', '.join(ids) or '(none)'}" for name, ids in others.items()]
    return lines


def fleet_summary(config: Config, source: str) -> str:
    """A fleet file checked without --gateway: every gateway's view is valid; who polls what."""
    lines = [f"{source}: valid for every gateway ({len(config.fleet)})"]
    for name, ids in config.fleet.items():
        lines.append(f"  gateway {name:<12} {len(ids)} machine(s): {', '.join(ids) or '(none)'}")
    return "\n".join(lines)
