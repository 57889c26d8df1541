"""Many simulated CNCs in one process, on consecutive ports.

A Fleet owns one Machine per MachineSpec: its MachineState, its FaultPlan, its native FOCAS server and,
when asked for, its packed-surface server over the same state. Tests drive machines in-process through
these objects (``fleet[0].state.write_macro(...)``, ``fleet[0].faults.hang = 1``,
``fleet[0].requests``); another process uses the admin endpoint (edge.sim.admin).

``async with Fleet(specs) as fleet:`` inside an event loop; ``with FleetThread(fleet) as fleet:`` runs it
on a private loop in a background thread for synchronous callers (blocking clients such as pyfocas,
CLI tests).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from edge.sim.faults import FaultPlan
from edge.sim.native_server import NativeServer
from edge.sim.profiles import get_profile
from edge.sim.state import MachineState
from edge.sim.state_program import CycleSpec

log = logging.getLogger(__name__)

DEFAULT_PORT = 8193
DEFAULT_ALARM_EVERY = 3  # a fleet machine raises (and clears) an alarm between parts every 3rd cycle


@dataclass
class MachineSpec:
    """How to build one simulated machine (a scenario file entry, or defaults)."""

    name: str = ""
    profile: str = "30i"
    timezone: str = "UTC"
    clock_offset: float = 0.0
    cycle: CycleSpec = field(default_factory=lambda: CycleSpec(alarm_every=DEFAULT_ALARM_EVERY))
    seed: int | None = None
    start_parts: int = 0
    param_write_enabled: bool = False
    macros: dict[int, float | None] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    clock_macro: int | None = None  # a macro that reads as the CNC's clock when it answers (MachineState)


class Machine:
    """One simulated CNC of a fleet: state + faults + servers."""

    def __init__(self, index: int, spec: MachineSpec, host: str, port: int, packed_port: int | None,
                 time_source: Callable[[], float]) -> None:
        self.index = index
        self.spec = spec
        profile = get_profile(spec.profile)
        self.name = spec.name or f"cnc{index + 1}"
        self.state = MachineState(profile, name=self.name, time_source=time_source, timezone=spec.timezone,
                                  clock_offset=spec.clock_offset, cycle=spec.cycle,
                                  seed=index if spec.seed is None else spec.seed,
                                  start_parts=spec.start_parts)
        self.state.param_write_enabled = spec.param_write_enabled
        self.state.clock_macro = spec.clock_macro
        for number, value in spec.macros.items():
            self.state.write_macro(number, value, protocol="scenario")
        self.faults = FaultPlan()
        self.faults.update(spec.faults)
        self.native = NativeServer(self.state, self.faults, host=host, port=port)
        self.host = host
        self._packed_port = packed_port
        self.packed: Any = None  # edge.sim.packed_server.PackedServer when started

    @property
    def port(self) -> int:
        """The native FOCAS port (bound; 0 before start when asked for any free port)."""
        return self.native.port

    @property
    def packed_port(self) -> int | None:
        return int(self.packed.port) if self.packed is not None else None

    @property
    def requests(self) -> int:
        """Data request PDUs the native server has answered (or dropped): the batch counter."""
        return self.native.stats.data_pdus

    @property
    def sessions(self) -> int:
        return self.native.sessions

    def drop_connections(self) -> int:
        """Abort every open native session now."""
        return self.native.drop_connections()

    async def start(self) -> None:
        await self.native.start()
        if self._packed_port is not None:
            from edge.sim.packed_server import start_packed_server

            self.packed = await start_packed_server(self.state, self.host, self._packed_port)

    async def close(self) -> None:
        await self.native.close()
        if self.packed is not None:
            await self.packed.close()
            self.packed = None

    def describe(self) -> dict[str, Any]:
        """JSON-friendly view (admin GET /machines)."""
        return {"index": self.index, "host": self.host, "port": self.port, "packed_port": self.packed_port,
                "requests": self.requests, "sessions": self.sessions, "stats": self.native.stats.describe(),
                "faults": self.faults.describe(), **self.state.snapshot()}


class Fleet:
    """Machines on consecutive ports from base_port (base_port 0: each on any free port, for tests)."""

    def __init__(self, specs: Sequence[MachineSpec], *, host: str = "127.0.0.1",
                 base_port: int = DEFAULT_PORT,
                 packed_base_port: int | None = None,
                 time_source: Callable[[], float] = time.time) -> None:
        if not specs:
            raise ValueError("a fleet needs at least one machine")
        self.host = host
        self.machines = [
            Machine(i, spec, host, base_port + i if base_port else 0,
                    None if packed_base_port is None else (packed_base_port + i if packed_base_port else 0),
                    time_source)
            for i, spec in enumerate(specs)
        ]

    @classmethod
    def uniform(cls, count: int, profile: str = "30i", **kwargs: Any) -> Fleet:
        """`count` machines; `profile` may be a comma list ("30i,16i,0i-F") used in turn."""
        profiles = [p.strip() for p in profile.split(",") if p.strip()]
        for name in profiles:
            get_profile(name)  # fail early with the list of known profiles
        return cls([MachineSpec(profile=profiles[i % len(profiles)]) for i in range(count)], **kwargs)

    def __getitem__(self, index: int) -> Machine:
        return self.machines[index]

    def __len__(self) -> int:
        return len(self.machines)

    def __iter__(self) -> Iterator[Machine]:
        return iter(self.machines)

    async def start(self) -> None:
        started: list[Machine] = []
        try:
            for machine in self.machines:
                await machine.start()
                started.append(machine)
        except BaseException:
            for machine in started:
                await machine.close()
            raise

    async def close(self) -> None:
        for machine in self.machines:
            await machine.close()

    async def __aenter__(self) -> Fleet:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()


class FleetThread:
    """Run a Fleet on its own event loop in a daemon thread: `with FleetThread(fleet) as fleet: ...`."""

    def __init__(self, fleet: Fleet) -> None:
        self.fleet = fleet
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="sim-fleet", daemon=True)

    def call(self, make: Callable[[], Any], timeout: float = 10.0) -> Any:
        """Run a coroutine made by `make` on the fleet's loop and wait for its result."""
        future: Future[Any] = asyncio.run_coroutine_threadsafe(make(), self._loop)
        return future.result(timeout)

    def __enter__(self) -> Fleet:
        self._thread.start()
        try:
            self.call(self.fleet.start)
        except BaseException:
            self._stop_loop()
            raise
        return self.fleet

    def __exit__(self, *exc_info: object) -> None:
        try:
            self.call(self.fleet.close)
        finally:
            self._stop_loop()

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()
