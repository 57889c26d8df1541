"""`focas-edge watch`: a live, decoded view of the Sparkplug and JSON traffic on a broker."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from edge import ConfigError
from edge.cli import EXIT_USAGE
from edge.config import GATEWAY_ENV
from edge.publish import PublishSettings

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 1883
DEFAULT_PREFIX = "focas"


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "watch", help="print decoded Sparkplug B and JSON messages as they arrive",
        description="Subscribe to a broker and print every focas-edge message readably: Sparkplug payloads are "
                    "decoded (aliases resolved from the births), JSON values shown with their quality and "
                    "CNC timestamp. With --config, the broker (with its TLS and login), the Sparkplug group, "
                    "the JSON prefix and the formats come from the daemon's config file; flags given as well "
                    "override it. Ctrl-C stops.",
        epilog="Exit codes: 0 stopped by Ctrl-C or SIGTERM, 2 bad usage or bad config. An unreachable broker "
               "is retried, not an error.")
    parser.add_argument("--config", "-c", type=Path, metavar="FILE",
                        help="take broker, group, JSON prefix and formats from this daemon config")
    parser.add_argument("--gateway", default=os.environ.get(GATEWAY_ENV) or None, metavar="NAME",
                        help="with a fleet file (gateways:), take the broker and ids of this gateway (default "
                             f"${GATEWAY_ENV}; without it, the first gateway's)")
    parser.add_argument("--host", help=f"broker host (default {DEFAULT_HOST})")
    parser.add_argument("--port", type=int, help=f"broker port (default {DEFAULT_PORT})")
    parser.add_argument("--group", help="Sparkplug group id to watch (default: all)")
    parser.add_argument("--json-prefix", help=f"JSON topic prefix (default {DEFAULT_PREFIX})")
    parser.add_argument("--no-json", action="store_true", help="Sparkplug only")
    parser.add_argument("--no-sparkplug", action="store_true", help="JSON only")
    parser.add_argument("--births", choices=["full", "summary"], default="summary",
                        help="print every metric of a birth (full) or one line (summary, default)")
    parser.set_defaults(func=handle)


@dataclass
class WatchPlan:
    """Where to connect and what to subscribe to."""

    host: str
    port: int
    topics: list[str]
    credentials: PublishSettings | None = None


def watch_plan(args: argparse.Namespace) -> WatchPlan:
    """The plan from the flags, on top of the config file when one is named (ConfigError if it is bad)."""
    host, port, group, prefix = DEFAULT_HOST, DEFAULT_PORT, "+", DEFAULT_PREFIX
    sparkplug, json_topics = True, True
    credentials = None
    if args.config is not None:
        from edge.config import load_config
        from edge.service.settings import publish_settings

        credentials = publish_settings(load_config(args.config, gateway=getattr(args, "gateway", None)))
        host, port, prefix = credentials.host, credentials.port, credentials.json_prefix
        group = credentials.group_id if "sparkplug" in credentials.formats else group
        sparkplug, json_topics = "sparkplug" in credentials.formats, "json" in credentials.formats
    host = args.host or host
    port = args.port or port
    topics = []
    if sparkplug and not args.no_sparkplug:
        topics += [f"spBv1.0/{args.group or group}/#", "spBv1.0/STATE/#"]
    if json_topics and not args.no_json:
        topics.append(f"{args.json_prefix or prefix}/#")
    return WatchPlan(host, port, topics, credentials)


def handle(args: argparse.Namespace) -> int:
    from edge.cli.views.watch import Watcher

    try:
        plan = watch_plan(args)
    except ConfigError as exc:
        print(f"focas-edge watch: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if not plan.topics:
        print("focas-edge watch: nothing to watch (both formats are off)", file=sys.stderr)
        return EXIT_USAGE
    print(f"watching {plan.host}:{plan.port} {' '.join(plan.topics)}", file=sys.stderr, flush=True)
    watcher = Watcher(plan.host, plan.port, plan.topics, printer=lambda line: print(line, flush=True),
                      show_births=args.births == "full", credentials=plan.credentials)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    watcher.start()
    try:
        done.wait()
    except KeyboardInterrupt:
        pass
    finally:
        watcher.stop()
    return 0
