"""`focas-edge watch`: a live, decoded view of the Sparkplug and JSON traffic on a broker."""

from __future__ import annotations

import argparse
import signal
import threading


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "watch", help="print decoded Sparkplug B and JSON messages as they arrive",
        description="Subscribe to a broker and print every focas-edge message readably: Sparkplug payloads are "
                    "decoded (aliases resolved from the births), JSON values shown with their quality and "
                    "CNC timestamp. Ctrl-C stops.",
        epilog="Exit codes: 0 stopped by Ctrl-C or SIGTERM, 2 bad usage. An unreachable broker is retried, "
               "not an error.")
    parser.add_argument("--host", default="127.0.0.1", help="broker host (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=1883, help="broker port (default 1883)")
    parser.add_argument("--group", default="+", help="Sparkplug group id to watch (default: all)")
    parser.add_argument("--json-prefix", default="focas", help="JSON topic prefix (default focas)")
    parser.add_argument("--no-json", action="store_true", help="Sparkplug only")
    parser.add_argument("--no-sparkplug", action="store_true", help="JSON only")
    parser.add_argument("--births", choices=["full", "summary"], default="summary",
                        help="print every metric of a birth (full) or one line (summary, default)")
    parser.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from edge.watch import Watcher

    topics = []
    if not args.no_sparkplug:
        topics += [f"spBv1.0/{args.group}/#", "spBv1.0/STATE/#"]
    if not args.no_json:
        topics.append(f"{args.json_prefix}/#")
    watcher = Watcher(args.host, args.port, topics, printer=lambda line: print(line, flush=True),
                      show_births=args.births == "full")
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
