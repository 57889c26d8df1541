"""`focas-edge init ADDRESS...`: probe each CNC (read-only) and write a config that polls what it answered."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import re
import socket
import sys
import time
from pathlib import Path
from typing import Any

from edge import ConfigError
from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from edge.cli.acl import account_names

DEFAULT_TIMEOUT = 5.0
DEFAULT_GROUP = "plant"


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "init", help="probe CNCs and write a commented config that polls what each answered",
        description="Probe each CNC read-only (as `probe` does: one request per read function, nothing is "
                    "written) and write a commented YAML config: a machine per address, each polling what its "
                    "control answered with data, status periods from the status group timed as one batch, as the "
                    "daemon sends it, writes off. "
                    "Check the result with `focas-edge check-config FILE`.",
        epilog="Exit codes: 0 every CNC probed and the config written, 1 a CNC could not be reached (the config "
               "is still written for the others, the missing ones as comments; nothing is written when none "
               "answered), 2 bad usage or an output file that exists (use --force).")
    parser.add_argument("addresses", nargs="+", metavar="HOST[:PORT]", help="CNC addresses (default port 8193)")
    parser.add_argument("--names", help="comma-separated machine ids, one per address (default: from the address)")
    parser.add_argument("--broker", default="localhost", metavar="HOST[:PORT]",
                        help="MQTT broker for the config (default localhost:1883)")
    parser.add_argument("--group", default=DEFAULT_GROUP, help=f"Sparkplug group id (default {DEFAULT_GROUP})")
    parser.add_argument("--node", help="Sparkplug edge node id (default: this host's name)")
    parser.add_argument("--transport", choices=("focas", "packed"), default="focas",
                        help="focas: native FOCAS/Ethernet (default); packed: the packed-buffer surface")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, metavar="SECONDS",
                        help=f"connect and per-request timeout (default {DEFAULT_TIMEOUT:g})")
    parser.add_argument("--output", "-o", default="-", metavar="FILE", help="where to write (default: stdout)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output file")
    parser.add_argument("--units", metavar="DIR",
                        help="also write the systemd units and drop-ins the package carries into DIR, running this "
                             "installation's focas-edge (e.g. a venv's: then `systemctl link` them or copy them to "
                             "/etc/systemd/system)")
    parser.add_argument("--acl", nargs="?", const="", metavar="FILE",
                        help="also write a mosquitto acl_file in which only the MES account may send commands and "
                             "only the gateway's account may publish its topics (default FILE: mosquitto.acl beside "
                             "the config; see docs/writes.md)")
    parser.add_argument("--acl-users", default="edge:mes", metavar="GATEWAY:MES",
                        help="the broker accounts the ACL names (default edge:mes)")
    parser.set_defaults(func=handle)


def _usage(message: str) -> int:
    print(f"focas-edge init: {message}", file=sys.stderr)
    return EXIT_USAGE


def _ids(args: argparse.Namespace) -> list[str]:
    """The machine ids, checked; ValueError says what is wrong."""
    from edge.config import check_sparkplug_id
    from edge.config.init_writer import machine_id_for

    if args.names is None:
        ids = [machine_id_for(address) for address in args.addresses]
    else:
        ids = [name.strip() for name in args.names.split(",")]
        if len(ids) != len(args.addresses):
            raise ValueError(f"--names has {len(ids)} name(s) for {len(args.addresses)} address(es)")
    for machine_id in ids:
        check_sparkplug_id(machine_id)
    lowered = [machine_id.lower() for machine_id in ids]
    twice = sorted({machine_id for machine_id in ids if lowered.count(machine_id.lower()) > 1})
    if twice:
        raise ValueError(f"machine id(s) given twice (ids ignore case): {', '.join(twice)}")
    return ids


def _check_hosts(args: argparse.Namespace) -> None:
    """A mistyped address (192.168.10.577) is a usage error naming it, before anything is probed."""
    from edge.config.fields import check_host
    from edge.focas.connect import parse_address

    for address in [*args.addresses, args.broker]:
        host = parse_address(address).host
        if host:  # empty for unix:/path
            try:
                check_host(host)
            except ValueError as exc:
                raise ValueError(f"{address}: {exc}") from None


def _broker(text: str) -> tuple[str, int]:
    from edge.focas.connect import parse_address

    parsed = parse_address(text, default_port=1883)
    return parsed.host, parsed.port


async def _probe_all(args: argparse.Namespace, ids: list[str]) -> list[Any]:
    from edge.config.init_writer import ProbedMachine
    from edge.focas.connect import open_session, parse_address
    from edge.focas.probe import probe

    async def one(address: str, machine_id: str) -> ProbedMachine:
        parsed = parse_address(address, default_port=8193 if args.transport == "focas" else 18193)
        session: Any = open_session(args.transport, f"{parsed.host}:{parsed.port}", timeout=args.timeout,
                                    connect_timeout=args.timeout)
        report = await probe(session, address)
        return ProbedMachine(machine_id, parsed.host, parsed.port, args.transport, report)

    return list(await asyncio.gather(*(one(a, i) for a, i in zip(args.addresses, ids, strict=True))))


STATUS_BATCH_TRIES = 3  # the fastest of these: the daemon sends the same request every tick, warm


async def _time_status_batches(reached: list[Any], draft: str) -> list[Any]:
    """Each machine's status group timed as the daemon will send it: the session and plan the daemon builds
    from the config written (`draft`), the group and the clock in one batched request."""
    from dataclasses import replace

    from edge.collect import plan as pl
    from edge.collect.poller import default_session
    from edge.collect.tick_batch import TickBatch
    from edge.config import parse_config
    from edge.focas.errors import FocasError
    from edge.service.settings import machine_settings

    config = parse_config(draft, source="the config written", secrets=False)
    by_id = {machine.id: machine for machine in config.machines}

    async def one(probed: Any) -> Any:
        settings = machine_settings(config, by_id[probed.id])
        items = TickBatch.build(pl.MachinePlan.build(settings.poll).reads_for({pl.Group.STATUS})).items
        session = default_session(settings)
        fastest = math.inf
        try:
            await session.connect()
            for _ in range(STATUS_BATCH_TRIES):
                started = time.perf_counter()
                await session.batch(items)
                fastest = min(fastest, time.perf_counter() - started)
        except FocasError:  # not timed: the writer falls back to the probe's round trips, summed
            return probed
        finally:
            await session.close()
        return replace(probed, status_batch_ms=round(fastest * 1000, 2))

    return list(await asyncio.gather(*(one(probed) for probed in reached)))


SNIFF_S = 1.5  # how long a port that answered may take to say what it is (SSH, FTP, telnet greet first)


async def what_answered(host: str, port: int, probe_error: str, timeout: float) -> str | None:
    """What answered at an address the FOCAS probe failed on; None when nothing did (refused, unreachable,
    or a port that accepts and says nothing).

    Listen-only: nothing is sent, so a device that is not a CNC gets no bytes from this look. The probe's own
    error still says how the FOCAS hello was answered (an HTTP server answers it with 'HTTP').
    """
    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), timeout)
    except (OSError, TimeoutError):
        return None
    try:
        try:
            data = await asyncio.wait_for(reader.read(256), min(timeout, SNIFF_S))
        except (OSError, TimeoutError):
            data = None
    finally:
        writer.close()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(writer.wait_closed(), 1.0)
    if data:
        return f"it sent {greeting(data)}"
    if data == b"":
        return f"it accepted the connection and closed it; the FOCAS hello got: {readable_error(probe_error)}"
    if "got " in probe_error:  # silent until spoken to, then not FOCAS (an HTTP server)
        return f"the FOCAS hello got: {readable_error(probe_error)}"
    return None  # a port that accepts and stays silent: maybe a busy CNC, so "not reached", not "not FOCAS"


def greeting(data: bytes) -> str:
    """A service's first bytes for people: its first line if it is text, else hex."""
    line = data.split(b"\n", 1)[0].rstrip(b"\r")
    if line and all(32 <= byte < 127 for byte in line):
        return repr(line[:80].decode("ascii"))
    return f"{len(data)} byte(s) {data[:16].hex(' ')}"


def readable_error(error: str) -> str:
    """The probe's error, with the bytes it quotes in hex also shown as text when they are (e.g. 'HTTP')."""
    def text(match: re.Match[str]) -> str:
        raw = bytes.fromhex(match[1])
        return match[0] + (f" ({raw.decode('ascii')!r})" if all(32 <= b < 127 for b in raw) else "")
    return re.sub(r"got ([0-9a-f]{8})\b", text, error)


def installation_command() -> str:
    """The focas-edge command of the installation running now, for the units' ExecStart.

    The environment's own script (a venv's bin/focas-edge, or /opt/focas-edge's from the .deb), else the
    script this process was started as, else this Python with `-m edge`.
    """
    script = Path(sys.prefix) / "bin" / "focas-edge"
    if script.is_file():
        return str(script)
    started_as = Path(sys.argv[0])
    if started_as.name == "focas-edge" and started_as.is_file():
        return str(started_as.absolute())
    return f"{Path(sys.executable).absolute()} -m edge"


def _service_reach(command: str) -> list[str]:
    """What the service user could not read of this installation (a venv in a 0700 home, say)."""
    from edge.config.service_access import SERVICE_USER, lookup_account, unreadable_file

    try:
        account = lookup_account(SERVICE_USER)
    except KeyError:
        return [f"no user {SERVICE_USER} yet, which the units run as: create it (adduser --system --group "
                f"{SERVICE_USER}) and make sure it can read {Path(command.split()[0]).parent}"]
    programs = {Path(command.split()[0]), Path(sys.executable).resolve()}
    return [p for p in (unreadable_file(account, "ExecStart", program) for program in sorted(programs)) if p]


async def _what_answered_all(failed: list[Any], timeout: float) -> list[str | None]:
    return list(await asyncio.gather(*(what_answered(m.host, m.port, m.report.error, timeout) for m in failed)))


def handle(args: argparse.Namespace) -> int:
    from edge.config.init_writer import render_config

    if args.timeout <= 0:
        return _usage(f"--timeout must be positive, got {args.timeout:g}")
    output = None if args.output == "-" else Path(args.output)
    if output is not None and output.exists() and not args.force:
        return _usage(f"{output} exists; use --force to overwrite it")
    acl = _acl_path(args, output)
    if acl is not None and acl.exists() and not args.force:
        return _usage(f"{acl} exists; use --force to overwrite it")
    users = account_names(args.acl_users)
    if users is None:
        return _usage(f"--acl-users {args.acl_users!r}: expected GATEWAY:MES, two different account names")
    if args.units is not None:
        from edge.config.bundled import write_bundled

        command = installation_command()
        try:
            units = write_bundled("systemd", Path(args.units), overwrite=args.force, command=command)
        except (FileExistsError, OSError) as exc:
            return _usage(f"--units {args.units}: {exc}")
        print(f"wrote {', '.join(u.name for u in units)} to {args.units}, running {command}", file=sys.stderr)
        for warning in _service_reach(command):
            print(f"focas-edge init: warning: {warning}", file=sys.stderr)
    try:
        ids = _ids(args)
        _check_hosts(args)
        broker_host, broker_port = _broker(args.broker)
        node = args.node or re.sub(r"[^A-Za-z0-9_.-]+", "-", socket.gethostname()) or "gateway"
        from edge.config import check_sparkplug_id

        check_sparkplug_id(args.group)
        check_sparkplug_id(node)
        probed = asyncio.run(_probe_all(args, ids))
    except (ValueError, ConfigError) as exc:
        return _usage("; ".join(exc.problems) if isinstance(exc, ConfigError) else str(exc))
    reached = [m for m in probed if m.report.complete]
    failed = [m for m in probed if not m.report.complete]
    answered = asyncio.run(_what_answered_all(failed, args.timeout))
    missed = [(m.report.address, m.report.error) for m, what in zip(failed, answered, strict=True) if what is None]
    not_focas = [(f"{m.host}:{m.port}", what) for m, what in zip(failed, answered, strict=True) if what is not None]
    for address, reason in missed:
        print(f"focas-edge init: {address}: {reason}", file=sys.stderr)
    for address, what in not_focas:
        print(f"focas-edge init: {address} answered but not FOCAS: {what}", file=sys.stderr)
    if not reached:
        print("focas-edge init: no CNC answered; nothing written", file=sys.stderr)
        return EXIT_FAILURE
    reached = asyncio.run(_time_status_batches(reached, render_config(reached, [], broker_host, broker_port,
                                                                       args.group, node)))
    text = render_config(reached, missed, broker_host, broker_port, args.group, node, not_focas)
    if acl is not None:
        _write_acl(acl, text, users[0], users[1])
    if output is None:
        sys.stdout.write(text)
    else:
        output.write_text(text, encoding="utf-8")
        print(f"wrote {output}: {len(reached)} machine(s); check it with `focas-edge check-config {output}`",
              file=sys.stderr)
    return EXIT_FAILURE if failed else EXIT_OK


def _acl_path(args: argparse.Namespace, output: Path | None) -> Path | None:
    """Where --acl writes: the path given, else mosquitto.acl beside the config (or here, for stdout)."""
    if args.acl is None:
        return None
    if args.acl:
        return Path(args.acl)
    return (output.parent if output is not None else Path.cwd()) / "mosquitto.acl"


def _write_acl(path: Path, config_text: str, gateway_user: str, mes_user: str) -> None:
    """The ACL for the config just rendered, read back as the daemon will read it (prefixes, ids)."""
    from edge.config import parse_config
    from edge.service.broker_acl import render_acl

    config = parse_config(config_text, source="the config written", secrets=False)
    path.write_text(render_acl(config, gateway_user, mes_user), encoding="utf-8")
    print(f"wrote {path}: only account {mes_user!r} may send commands, only {gateway_user!r} may publish as the "
          f"gateway; in mosquitto.conf: allow_anonymous false, password_file FILE, acl_file {path.absolute()}",
          file=sys.stderr)
