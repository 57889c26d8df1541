"""`focas-edge sim`: run a fleet of simulated CNCs until Ctrl-C / SIGTERM.

    focas-edge sim --machines 3 --port 8193 --profile 30i,16i,0i-F --admin-port 8190
    focas-edge sim --scenario fleet.yaml

Prints one line per machine (name, profile, native port, packed port if any) and the admin URL, then
"ready". Exit 0 on a clean stop, 1 when a port cannot be bound, 2 on bad usage or a bad scenario.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
import textwrap
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from edge import ConfigError
from edge.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE

EXIT_CODES = ("Exit codes: 0 stopped by Ctrl-C or SIGTERM, 1 a port could not be bound, 2 bad usage or a bad "
              "scenario file.")
PROFILES_AND_EXIT_CODES = "\0profiles and exit codes\0"  # expanded by _SimHelp when help is printed


class _SimHelp(argparse.RawDescriptionHelpFormatter):
    """Lists every simulator profile, one line each, when the help is printed: the profile table lives in the
    simulator, which the CLI does not import just to parse its arguments."""

    def add_text(self, text: str | None) -> None:
        if text == PROFILES_AND_EXIT_CODES:
            from edge.sim.profiles import profile_lines

            text = "\n".join(["profiles (--profile):", *(f"  {line}" for line in profile_lines()), "",
                              textwrap.fill(EXIT_CODES, width=self._width)])
        super().add_text(text)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "sim", help="run simulated CNCs (native FOCAS/Ethernet, optionally the packed surface)",
        description=textwrap.fill("Run simulated FANUC CNCs on consecutive ports until Ctrl-C or SIGTERM. See "
                                  "docs/simulator.md for profiles, faults, the admin endpoint and scenario files."),
        epilog=PROFILES_AND_EXIT_CODES, formatter_class=_SimHelp)
    parser.add_argument("--machines", type=int, default=None, metavar="N", help="how many (default 1)")
    parser.add_argument("--port", type=int, default=None, metavar="PORT",
                        help="native FOCAS port of the first machine; the next ones follow (default 8193; "
                             "0 = any free port each)")
    parser.add_argument("--host", default=None, help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--profile", default="30i", metavar="NAME[,NAME...]",
                        help="a profile listed below; a comma list is used in turn (default 30i)")
    parser.add_argument("--packed-port", type=int, default=None, metavar="PORT",
                        help="also serve the packed surface, first machine on PORT")
    parser.add_argument("--admin-port", type=int, default=None, metavar="PORT",
                        help="serve the HTTP/JSON admin endpoint on PORT (see docs/simulator.md)")
    parser.add_argument("--scenario", default=None, metavar="FILE",
                        help="YAML scenario (machines, profiles, time zones, clock offsets, faults); "
                             "--host/--port/--packed-port/--admin-port override it")
    parser.add_argument("--timezone", default="UTC", help="CNC time zone (IANA name, default UTC)")
    parser.add_argument("--clock-offset", type=float, default=0.0, metavar="SECONDS",
                        help="CNC clock minus real time (default 0)")
    parser.add_argument("--cut-seconds", type=float, default=12.0, help="cutting time per part (default 12)")
    parser.add_argument("--idle-seconds", type=float, default=4.0, help="time between parts (default 4)")
    parser.add_argument("--alarm-every", type=int, default=3, metavar="N",
                        help="raise and clear an alarm between parts every N cycles (0 = never; default 3)")
    parser.add_argument("--param-write-enable", action="store_true",
                        help="start with the parameter-write-enable switch on")
    parser.set_defaults(func=run_sim)


def build_scenario(args: argparse.Namespace) -> Any:
    """The Scenario the arguments describe (a file, or the flags)."""
    from edge.sim import CycleSpec, MachineSpec, Scenario, get_profile, load_scenario

    if args.scenario:
        if args.machines is not None:
            raise ConfigError(["--machines cannot be combined with --scenario"], "command line")
        scenario: Scenario = load_scenario(args.scenario)
    else:
        count = 1 if args.machines is None else args.machines
        if count < 1:
            raise ConfigError([f"--machines must be at least 1, got {count}"], "command line")
        profiles = [p.strip() for p in args.profile.split(",") if p.strip()]
        try:
            for name in profiles:
                get_profile(name)
            ZoneInfo(args.timezone)
            cycle = CycleSpec(cut_seconds=args.cut_seconds, idle_seconds=args.idle_seconds,
                              alarm_every=max(0, args.alarm_every))
        except (ValueError, ZoneInfoNotFoundError) as exc:
            raise ConfigError([str(exc)], "command line") from None
        scenario = Scenario([MachineSpec(profile=profiles[i % len(profiles)], timezone=args.timezone,
                                         clock_offset=args.clock_offset, cycle=cycle,
                                         param_write_enabled=args.param_write_enable)
                             for i in range(count)])
    for attribute in ("host", "packed_port", "admin_port", "port"):
        value = getattr(args, attribute)
        if value is not None:
            target = {"port": "base_port", "packed_port": "packed_base_port"}.get(attribute, attribute)
            setattr(scenario, target, value)
    return scenario


def run_sim(args: argparse.Namespace) -> int:
    try:
        scenario = build_scenario(args)
    except ConfigError as exc:
        print(f"focas-edge sim: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        return asyncio.run(serve(scenario))
    except OSError as exc:
        print(f"focas-edge sim: cannot listen: {exc}", file=sys.stderr)
        return EXIT_FAILURE


async def serve(scenario: Any) -> int:
    """Run the fleet (and admin endpoint) until SIGINT/SIGTERM."""
    from edge.sim import AdminServer, Fleet

    fleet = Fleet(scenario.machines, host=scenario.host, base_port=scenario.base_port,
                  packed_base_port=scenario.packed_base_port)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    async with fleet:
        admin = None
        if scenario.admin_port is not None:
            admin = AdminServer(fleet, scenario.host, scenario.admin_port)
            await admin.start()
        try:
            for machine in fleet:
                packed = f"  packed {machine.host}:{machine.packed_port}" if machine.packed_port else ""
                print(f"{machine.name:<12} {machine.state.profile.name:<5} "
                      f"focas {machine.host}:{machine.port}{packed}", flush=True)
            if admin is not None:
                print(f"admin        {admin.url}/machines", flush=True)
            print("ready (Ctrl-C to stop)", flush=True)
            await stop.wait()
        finally:
            if admin is not None:
                await admin.close()
    return EXIT_OK
