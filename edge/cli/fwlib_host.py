"""`focas-edge fwlib-host --config FILE`: serve the packed surface through FANUC's FOCAS library.

Prints one line per machine (name, CNC address, where it is served), then "ready". Exit 0 on SIGTERM or
Ctrl-C, 2 on a bad config file or a library that cannot be loaded (the message names the path and, for an
architecture mismatch, both architectures), 1 when an address cannot be bound.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
from pathlib import Path
from typing import Any

from edge import ConfigError
from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "fwlib-host", help="serve the packed surface through FANUC's FOCAS library (alarm history, writes)",
        description="Load FANUC's FOCAS library (libfwlib32.so / Fwlib32.dll / Fwlib64.dll, from your FOCAS2 "
                    "kit; focas-edge does not ship it) and serve the packed surface for each configured CNC on "
                    "a Unix socket or loopback TCP. The daemon connects with transport: packed (or fwlib_host). "
                    "See docs/install.md.",
        epilog="Exit codes: 0 stopped by SIGTERM/SIGINT, 1 an address could not be bound, 2 a bad config file "
               "or a library that cannot be loaded.")
    parser.add_argument("--config", "-c", type=Path, default=Path("/etc/focas-edge/fwlib-host.yaml"),
                        help="the host's YAML file (default /etc/focas-edge/fwlib-host.yaml)")
    parser.add_argument("--library", default=None, metavar="PATH", help="the FOCAS library (overrides the file)")
    parser.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from edge.fwlib.library import LibraryLoadError, load_library
    from edge.fwlib.settings import load_settings

    try:
        settings = load_settings(args.config)
        if args.library:
            settings = settings.model_copy(update={"library": args.library})
        return asyncio.run(serve(settings, load_library(settings.library)))
    except (ConfigError, LibraryLoadError) as exc:
        print(f"focas-edge fwlib-host: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:
        print(f"focas-edge fwlib-host: cannot listen: {exc}", file=sys.stderr)
        return EXIT_FAILURE


async def serve(settings: Any, library: Any) -> int:
    """Serve until SIGINT/SIGTERM; tell systemd READY=1 once every endpoint listens."""
    from edge.fwlib.host import start_host
    from edge.service.sdnotify import SystemdNotifier

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    host = await start_host(settings, library)
    notifier = SystemdNotifier()
    try:
        for machine in settings.machines:
            print(f"{machine.name:<12} cnc {machine.cnc:<22} packed {host.endpoints[machine.name].address}",
                  flush=True)
        print("ready (Ctrl-C to stop)", flush=True)
        notifier.ready()
        await stop.wait()
        notifier.stopping()
    finally:
        await host.close()
    return EXIT_OK
