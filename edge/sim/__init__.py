"""The simulated CNC: the machine model and the servers that speak FOCAS for it (demo, tests, benchmarks).

What lives here:
  state, state_*     MachineState, one simulated control (per path), its state split by area:
                     macros, PMC, parameters/diagnosis, alarms, program/cycle, motion, clock, write log
  profiles           what a 0i-F, 16i, 30i, 31i (and two-path 31i) says about itself
  native_handlers    one handler per FOCAS function; answer_subpacket, the reference answer
  native_plans       the fast path: answers compiled per request, byte-identical to the reference
  native_server      NativeServer: native FOCAS/Ethernet over asyncio
  packed_server      the packed-buffer surface over the same state
  faults             FaultPlan: latency, drops, hangs, forced EW codes, changeable at runtime
  fleet              Fleet / Machine / FleetThread: many machines on consecutive ports
  admin              AdminServer: HTTP/JSON control of a running fleet
  scenario           YAML scenario files -> MachineSpecs

What it may import:
1. The focas codecs, to serve with the very layouts the client reads (one table, so the simulator can
   never disagree with the client): edge.focas.frame, functions, values, model, errors, packed and
   packed_frame, packed_endpoint (the server side of the packed surface); edge.ConfigError for scenarios.
2. Never the client (edge.focas.client, session, connect, native, routed, packed_client): a simulator
   built on the client would agree with it by construction, bugs included.
3. Nothing above focas: not collect, publish, command, service, cli or config.
Other packages import the simulator through this module's `__all__`.
"""

from edge.sim.admin import AdminServer
from edge.sim.fleet import Fleet, FleetThread, Machine, MachineSpec
from edge.sim.native_handlers import answer_subpacket
from edge.sim.native_server import NativeServer, ServerStats
from edge.sim.packed_server import PackedServer, start_packed_server
from edge.sim.profiles import PROFILES, get_profile
from edge.sim.scenario import Scenario, load_scenario
from edge.sim.state import MachineState
from edge.sim.state_program import CycleSpec

__all__ = [
    "PROFILES",
    "AdminServer",
    "CycleSpec",
    "Fleet",
    "FleetThread",
    "Machine",
    "MachineSpec",
    "MachineState",
    "NativeServer",
    "PackedServer",
    "Scenario",
    "ServerStats",
    "answer_subpacket",
    "get_profile",
    "load_scenario",
    "start_packed_server",
]
