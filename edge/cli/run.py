"""`focas-edge run --config FILE`: the collector daemon."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from edge import ConfigError
from edge.cli import EXIT_USAGE
from edge.config import GATEWAY_ENV

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "run", help="run the collector daemon",
        description="Poll every configured CNC and publish what changes to MQTT (Sparkplug B 3.0 and/or JSON). "
                    "SIGTERM stops cleanly (DDEATH, NDEATH, close PDUs); SIGHUP reloads the config file. Under "
                    "systemd (Type=notify) it sends READY=1 once started and WATCHDOG=1 only while every poll loop "
                    "makes progress. With http.enabled in the config, /healthz and /metrics (Prometheus) are "
                    "served on http.host:http.port. See docs/config.md and docs/install.md.",
        epilog="Exit codes: 0 stopped by SIGTERM/SIGINT, 2 bad config (every problem listed; not restarted by "
               "the systemd unit), other non-zero an unexpected failure.")
    parser.add_argument("--config", "-c", type=Path, default=Path("/etc/focas-edge/edge.yaml"),
                        help="the YAML config file (default /etc/focas-edge/edge.yaml)")
    parser.add_argument("--gateway", default=os.environ.get(GATEWAY_ENV) or None, metavar="NAME",
                        help="in a fleet file with gateways:, the gateway this process is: it polls only the machines "
                             f"that name it (default ${GATEWAY_ENV}; docs/config.md, docs/install.md)")
    parser.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from edge.service.daemon import run_daemon

    try:
        return run_daemon(args.config, gateway=args.gateway)
    except ConfigError as exc:
        single = f"{exc.source}: {exc.problems[0]}" if len(exc.problems) == 1 else str(exc)
        print(f"focas-edge: {single}", file=sys.stderr)
        return EXIT_USAGE
