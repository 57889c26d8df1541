"""The focas-edge command: one module per subcommand, each with a register(subparsers) function.

Exit codes for every subcommand: 0 all ok, 1 a CNC or network error, 2 bad usage or bad config.

The top layer: cli may import every package below it (service, command, collect, publish, config, sim,
fwlib, focas); nothing imports cli. Subcommand modules are imported only when their subcommand runs, so
`focas-edge read` does not load the daemon. The terminal views (watch, the live view, the `make run` demo)
live in edge/cli/views/.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from edge import __version__
from edge.service.logformat import LOG_FORMATS, configure_logging

# Subcommand modules in the order `--help` lists them. Each defines
#   register(subparsers) -> None   adding its parser with set_defaults(func=handler)
# where handler(args) -> int returns the exit code.
SUBCOMMANDS = ["run", "sim", "read", "write", "probe", "init", "watch", "check_config", "acl", "fwlib_host"]

__all__ = ["EXIT_FAILURE", "EXIT_OK", "EXIT_PARTIAL", "EXIT_USAGE", "SUBCOMMANDS", "build_parser", "main"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_PARTIAL = 3  # `read`: every item answered something, but the CNC refused some parts of a composite
EXIT_BROKEN_PIPE = 141  # what a shell reports for a command killed by SIGPIPE


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="focas-edge",
        description="Edge collector for FANUC CNCs: FOCAS/Ethernet to MQTT (Sparkplug B 3.0 and JSON).",
    )
    parser.add_argument("--version", action="version", version=f"focas-edge {__version__}")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING or ERROR (default INFO)")
    parser.add_argument("--log-format", choices=LOG_FORMATS, default="text",
                        help="text (default) or json: one JSON object per line (ts, level, logger, message, "
                             "exc) for journald, Loki or ELK")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"edge.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"edge.cli.{name}":
                continue
            raise
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        configure_logging(args.log_level, args.log_format)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
        try:
            code = int(args.func(args))
        except KeyboardInterrupt:
            code = EXIT_OK
        sys.stdout.flush()  # here, so a reader gone away (`| head`) is seen below, not at interpreter exit
        return code
    except BrokenPipeError:
        return _reader_gone()


def _reader_gone() -> int:
    """stdout's reader closed the pipe (`check-config FILE | head -1`): stop quietly, as a Unix tool does.

    Python would print a BrokenPipeError traceback, and another one when it flushes stdout at exit; pointing
    stdout at /dev/null stops the second. The exit code is the shell's for a SIGPIPE death (128 + 13).
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
