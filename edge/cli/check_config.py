"""`focas-edge check-config FILE`: validate a config file without connecting to anything.

Exit 0 with a short summary of what the daemon would do; exit 2 with every problem listed, each with
its path in the file. Warnings (values that were adjusted) are printed either way.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from edge import ConfigError
from edge.cli import EXIT_OK, EXIT_USAGE
from edge.config import Config, load_config
from edge.config.service_access import SERVICE_USER, service_problems, state_dir_problem
from edge.opcua import missing_extra


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "check-config", help="validate a config file without connecting",
        description="Validate a focas-edge YAML config: every problem is listed with its path in the file. "
                    "Secrets named by password_env/password_file must be available, as they must be for run.",
        epilog="Exit codes: 0 valid, 2 invalid (every problem listed).")
    parser.add_argument("config", metavar="FILE", help="the YAML config file")
    parser.add_argument("--quiet", "-q", action="store_true", help="print nothing when the file is valid")
    parser.add_argument("--as-service", action="store_true",
                        help="also check that the systemd service's user can read every file the config names "
                             "and write state_dir (under the unit's ProtectSystem=strict)")
    parser.add_argument("--service-user", default=SERVICE_USER, metavar="NAME",
                        help=f"the service's user for --as-service (default {SERVICE_USER})")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        config = load_config(args.config)
        problems = usability_problems(config, args.service_user if args.as_service else None)
    except ConfigError as exc:
        problems = exc.problems
    if problems:
        print(f"{args.config}: invalid, {len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  {problem}", file=sys.stderr)
        return EXIT_USAGE
    for warning in config.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if not args.quiet:
        print(summary(config, args.config))
    return EXIT_OK


def usability_problems(config: Config, service_user: str | None) -> list[str]:
    """What the daemon could not use: a state_dir set in the file, and with a service user, its access."""
    problems = []
    if config.state_dir is not None:
        problems.append(state_dir_problem(config.state_dir))
    if service_user is not None:
        problems.extend(service_problems(config, service_user))
    if config.opcua.enabled:
        missing = missing_extra()
        problems.append(f"opcua.enabled: {missing}" if missing is not None else None)
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
        lines.append(f"  json       {mqtt.json_topics.prefix}/<machine>/...")
    if config.opcua.enabled:
        ua = config.opcua
        who = ", ".join([u.username for u in ua.users] + (["anonymous"] if ua.allow_anonymous else []))
        lines.append(f"  opcua      opc.tcp://{ua.host}:{ua.port}{ua.path}  security {', '.join(ua.security)}  "
                     f"users {who}")
    lines.append(f"  state_dir  {config.resolved_state_dir}")
    lines.append(f"  writes     {'enabled' if config.writes.enabled else 'disabled'}"
                 f" ({len(config.writes.allow)} global allow rule(s))")
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
