"""`make run`: a simulated fleet, a broker, the daemon and a live decoded view, in one process.

The fleet follows the example config (one simulated CNC per configured machine, profiles 30i / 16i /
0i-F in turn, a machine with `paths: 2` the two-path lathe 31i-2p, the first one running a program with
alarms coming and going). If no broker answers at
the configured address, an embedded broker (amqtt) is started there and the demo says so. Ctrl-C stops
everything cleanly: DDEATHs, NDEATH, close PDUs, broker, simulators.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import socket
import sys
from pathlib import Path
from typing import Any

from edge.cli.views.live_view import LiveView
from edge.cli.views.watch import Watcher
from edge.config import Config, MachineConfig, listen_port, load_config
from edge.service.daemon import Daemon
from edge.service.logformat import configure_logging
from edge.service.state_lock import held_message, holder
from edge.sim import CycleSpec, Fleet, MachineSpec

log = logging.getLogger("edge.cli.views.demo")

PROFILES = ("30i", "16i", "0i-F")
MULTI_PATH_PROFILE = "31i-2p"  # for a machine configured with paths: 2 (a twin-turret lathe)


NDEATH_WAIT_S = 3.0


def broker_answers(host: str, port: int) -> bool:
    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=0.5):
        return True
    return False


async def start_embedded_broker(host: str, port: int) -> Any:
    """A real MQTT broker in this process (amqtt), for machines without mosquitto."""
    from amqtt.broker import Broker

    broker = Broker({
        "listeners": {"default": {"type": "tcp", "bind": f"{host}:{port}"}},
        "plugins": {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}},
    }, loop=asyncio.get_running_loop())
    await broker.start()
    return broker


def fleet_specs(config: Config) -> list[MachineSpec]:
    specs = []
    for index, machine in enumerate(config.machines):
        cycle = CycleSpec(alarm_every=2, alarm_seconds=6.0) if index == 0 else CycleSpec(
            cut_seconds=9.0 + 3 * index, idle_seconds=3.0 + index)
        profile = MULTI_PATH_PROFILE if machine.paths > 1 else PROFILES[index % len(PROFILES)]
        specs.append(MachineSpec(name=machine.id, profile=profile,
                                 timezone=machine.timezone, cycle=cycle, param_write_enabled=False))
    return specs


async def start_fleet(config: Config) -> tuple[Fleet, Config]:
    """Simulators on the configured ports (or free ones if those are taken); the config points at them."""
    first = config.machines[0].port
    fleet = Fleet(fleet_specs(config), base_port=first, packed_base_port=0)
    try:
        await fleet.start()
    except OSError as exc:
        await fleet.close()
        log.warning("ports from %d are taken (%s): using free ports", first, exc)
        fleet = Fleet(fleet_specs(config), base_port=0, packed_base_port=0)
        await fleet.start()
    machines: list[MachineConfig] = []
    for machine, sim in zip(config.machines, fleet, strict=True):
        if machine.transport == "packed":
            machines.append(machine.model_copy(update={"host": None,
                                                       "address": f"tcp:127.0.0.1:{sim.packed_port}"}))
        else:
            update: dict[str, object] = {"host": "127.0.0.1", "port": sim.port}
            if machine.fwlib_host is not None:  # the simulator's packed surface stands in for fwlib-host
                update["fwlib_host"] = f"tcp:127.0.0.1:{sim.packed_port}"
            machines.append(machine.model_copy(update=update))
    return fleet, config.model_copy(update={"machines": machines})


def opcua_on_a_free_port(config: Config) -> Config:
    """The demo's OPC UA server moves to a free port when its own is taken (as the simulators do), and says so."""
    opcua = config.opcua
    if not opcua.enabled or listen_port.probe(opcua.host, opcua.port, "opcua") is None:
        return config
    with socket.socket() as sock:
        sock.bind((opcua.host, 0))
        port = sock.getsockname()[1]
    log.warning("OPC UA port %d is taken: using %d", opcua.port, port)
    return config.model_copy(update={"opcua": opcua.model_copy(update={"port": port})})


async def run_demo(config_path: Path, duration: float | None, raw: bool = False) -> int:
    config = load_config(config_path)
    running = holder(config.resolved_state_dir)
    if running is not None:  # a second `make run` on this checkout: say so before starting anything
        print(f"== {held_message(config.resolved_state_dir, running)}", flush=True)
        return 2
    config = opcua_on_a_free_port(config)
    fleet, config = await start_fleet(config)
    mqtt = config.mqtt
    port = mqtt.effective_port
    broker = None
    if broker_answers(mqtt.host, port):
        print(f"== using the MQTT broker at {mqtt.host}:{port}", flush=True)
    else:
        print(f"== no MQTT broker answered at {mqtt.host}:{port}: starting an embedded broker (amqtt) there",
              flush=True)
        broker = await start_embedded_broker(mqtt.host, port)
        if mqtt.protocol != "3.1.1":
            print("== the embedded broker speaks MQTT 3.1.1 only: the daemon uses 3.1.1 for this run", flush=True)
            mqtt = mqtt.model_copy(update={"protocol": "3.1.1"})
            config = config.model_copy(update={"mqtt": mqtt})
    for machine, sim in zip(config.machines, fleet, strict=True):
        where = machine.endpoint + (f" + library host {machine.fwlib_host}" if machine.fwlib_host else "")
        paths = f"  {machine.paths} paths" if machine.paths > 1 else ""
        print(f"== simulated CNC {machine.id:<10} profile {sim.state.profile.name:<5} at {where}{paths}", flush=True)
    prefix = mqtt.json_prefix
    group = mqtt.sparkplug.group_id if mqtt.sparkplug else "+"
    print(f"== subscribe: mosquitto_sub -h {mqtt.host} -p {port} -t 'spBv1.0/{group}/#' -t '{prefix}/#' -v",
          flush=True)
    print(f"== or:        .venv/bin/focas-edge watch --host {mqtt.host} --port {port}", flush=True)
    if config.opcua.enabled:
        opcua = config.opcua
        users = ", ".join(user.username for user in opcua.users) or "anonymous"
        print(f"== OPC UA:    opc.tcp://{opcua.host}:{opcua.port}{opcua.path} (user {users}; the README says how to "
              "browse it)", flush=True)
    print("== Ctrl-C stops everything" + ("" if raw else "; `make run RAW=1` shows every message decoded"),
          flush=True)

    daemon = Daemon(config)
    view = None if raw else LiveView(daemon)
    printer = (lambda line: print(line, flush=True)) if view is None else view.on_line
    watcher = Watcher(mqtt.host, port, [f"spBv1.0/{group}/#", f"{prefix}/#"], printer=printer, show_births=False)
    watcher.start()
    drawing = None if view is None else asyncio.create_task(view.run())
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, daemon.request_stop)
    if duration is not None:
        loop.call_later(duration, daemon.request_stop)
    try:
        code = await daemon.run()
    finally:
        if mqtt.sparkplug is not None:  # let the watcher print the NDEATH the daemon just sent
            await asyncio.to_thread(watcher.node_death_seen.wait, NDEATH_WAIT_S)
        if drawing is not None and view is not None:
            drawing.cancel()
            view.draw()
        watcher.stop()
        await fleet.close()
        if broker is not None:
            await broker.shutdown()
    print("== stopped cleanly", flush=True)
    return code


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m edge.cli.views.demo", description=__doc__)
    parser.add_argument("--config", type=Path, default=Path("config/edge.yaml"))
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--log-level", default="WARNING")
    parser.add_argument("--raw", action="store_true",
                        help="print every message decoded (the firehose) instead of the compact live view")
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    for noisy in ("amqtt", "transitions"):
        logging.getLogger(noisy).setLevel(logging.ERROR)
    return asyncio.run(run_demo(args.config, args.duration, args.raw))


if __name__ == "__main__":
    sys.exit(main())
