"""`focas-edge acl CONFIG`: the mosquitto acl_file for an existing gateway config.

`init --acl` writes one beside a config it has just made; a plant whose config already exists (edited by
hand, or from an older version) gets the same file from here, built from the topics the daemon will use.
Exit 0 written, 2 a bad config, bad accounts or a file that exists (without --force).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from edge import ConfigError
from edge.cli import EXIT_OK, EXIT_USAGE


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "acl", help="write the broker ACL for a gateway config (who may send commands, who may publish as it)",
        description="Print (or write) a mosquitto acl_file in which only the MES account may publish this "
                    "gateway's commands (DCMD, NCMD, <prefix>/<machine>/cmd) and only the gateway's account may "
                    "publish its topics. See docs/writes.md, \"Who may write\".",
        epilog="Exit codes: 0 written, 2 a bad config, bad account names or an existing file without --force.")
    parser.add_argument("config", type=Path, help="the gateway's config file (its secrets are not read)")
    parser.add_argument("--users", default="edge:mes", metavar="GATEWAY:MES",
                        help="the gateway's and the MES's broker accounts (default edge:mes)")
    parser.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                        help="write FILE instead of printing the ACL")
    parser.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    parser.set_defaults(func=run)


def account_names(text: str) -> tuple[str, str] | None:
    """GATEWAY:MES as two different names a mosquitto `user` line can hold, or None."""
    users = text.split(":")
    if len(users) != 2 or not all(users) or any(c in text for c in " #+/") or users[0] == users[1]:
        return None
    return users[0], users[1]


def run(args: argparse.Namespace) -> int:
    from edge.config import load_config
    from edge.service.broker_acl import render_acl

    users = account_names(args.users)
    if users is None:
        print(f"focas-edge acl: --users {args.users!r}: expected GATEWAY:MES, two different account names",
              file=sys.stderr)
        return EXIT_USAGE
    if args.output is not None and args.output.exists() and not args.force:
        print(f"focas-edge acl: {args.output} exists; use --force to overwrite it", file=sys.stderr)
        return EXIT_USAGE
    try:
        config = load_config(args.config, secrets=False)
    except ConfigError as exc:
        print(f"focas-edge acl: {'; '.join(exc.problems)}", file=sys.stderr)
        return EXIT_USAGE
    text = render_acl(config, *users)
    if args.output is None:
        sys.stdout.write(text)
        return EXIT_OK
    args.output.write_text(text, encoding="utf-8")
    print(f"wrote {args.output}: in mosquitto.conf: allow_anonymous false, password_file FILE, "
          f"acl_file {args.output.absolute()}", file=sys.stderr)
    return EXIT_OK
