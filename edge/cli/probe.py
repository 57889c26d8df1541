"""`focas-edge probe HOST[:PORT]`: identify a CNC and try every read function once (never writes)."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from typing import Any

from edge import ConfigError
from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE

DEFAULT_TIMEOUT = 5.0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "probe", help="identify a CNC and try every function once (for writing a poll plan)",
        description="Connect to one CNC, identify its series (sysinfo), then try every read function once, "
                    "each in its own request, and print which answer with data, which answer EW_FUNC or "
                    "EW_NOOPT (the control lacks the function or its option: leave it out of the poll "
                    "plan), which answer another EW code, and the round-trip time of each. On the native "
                    "transport the parameter/diagnosis reads are also tried in the other record form "
                    "(0x0e/0x30 vs 0x8d/0x93). Writes are checked without writing anything: the probe "
                    "reports whether the transport has each write and whether the read it pairs with works.",
        epilog="Outcomes: ok (data), not-available (EW_FUNC/EW_NOOPT), cnc-error (another EW code: the function "
               "exists, the probe's arguments did not suit this machine), not-supported (the transport has no "
               "wire form: nothing sent), failed (timeout or protocol error). "
               "Exit codes: 0 the probe completed (whatever the functions answered), 1 the CNC could not be "
               "reached or was lost during the probe, 2 bad usage.",
    )
    parser.add_argument("address", metavar="HOST[:PORT]",
                        help="CNC address: host, host:port (default port 8193; packed 18193), tcp:host:port, "
                             "or unix:/path (packed transport only)")
    parser.add_argument("--transport", choices=("focas", "packed"), default="focas",
                        help="focas: native FOCAS/Ethernet (default); packed: the packed-buffer surface")
    parser.add_argument("--fwlib-host", default=None, metavar="ADDRESS",
                        help="also a FOCAS library host (focas-edge fwlib-host: unix:/path or tcp:host:port) for "
                             "what the native transport lacks; each function then shows [native] or [fwlib-host]")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, metavar="SECONDS",
                        help=f"connect and per-request timeout (default {DEFAULT_TIMEOUT:g})")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON document (cnc, functions with outcome/rtt_ms/ew_code, writes)")
    parser.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from edge.focas.connect import open_session
    from edge.focas.probe import probe, report_json, report_lines

    if args.timeout <= 0:
        print(f"focas-edge probe: --timeout must be positive, got {args.timeout:g}", file=sys.stderr)
        return EXIT_USAGE
    try:
        session: Any = open_session(args.transport, args.address, fwlib_host=args.fwlib_host,
                                    timeout=args.timeout, connect_timeout=args.timeout)
    except ConfigError as exc:
        print(f"focas-edge probe: {'; '.join(exc.problems)}", file=sys.stderr)
        return EXIT_USAGE
    report = asyncio.run(probe(session, args.address))
    if args.json:
        print(json.dumps(report_json(report), indent=2))
    else:
        print("\n".join(report_lines(report)))
    if report.error:
        print(f"focas-edge probe: {args.address}: {report.error}", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK
