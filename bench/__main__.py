"""`python -m bench [name ...] [--quick] [--repeat N]`: run benchmarks, print tables, save JSON.

from bench import codec, fleet, floor, opcua, outage, plant_page, reload, roundtrip, writes
from bench.report import Result, machine_info, render, save

BENCHMARKS = ("codec", "roundtrip", "fleet", "floor", "writes", "plantpage", "opcua", "reload", "outage")
# opcua needs the [opcua] extra and takes minutes; reload and outage run 1,000 machines: asked for by name
DEFAULT = BENCHMARKS[:6]
"""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from bench import codec, fleet, floor, opcua, outage, plant_page, reload, roundtrip, writes
from bench.report import Result, machine_info, render, save

BENCHMARKS = ("codec", "roundtrip", "fleet", "floor", "writes", "plantpage", "opcua", "reload", "outage")
# opcua needs the [opcua] extra and takes minutes; reload and outage run 1,000 machines: asked for by name
DEFAULT = BENCHMARKS[:6]


def runners(args: argparse.Namespace) -> dict[str, Callable[[], Result]]:
    sizes = [int(n) for n in args.sizes.split(",")] if args.sizes else None
    spy = Path(args.spy) if args.spy else None

    def run_fleet() -> Result:
        periods = [float(p) for p in args.period.split(",")] if args.period else None
        result = fleet.run(quick=args.quick, sizes=sizes, repeats=args.repeat, duration_s=args.duration,
                           spy_to=spy, py_spy=args.py_spy, periods=periods, warmup_s=args.warmup,
                           tracemalloc_to=Path(args.tracemalloc) if args.tracemalloc else None,
                           diagnose=args.diagnose, same_plan=args.same_plan,
                           same_clock=args.same_clock)
        return result

    return {
        "codec": lambda: codec.run(quick=args.quick, repeats=max(args.repeat, 3)),
        "roundtrip": lambda: roundtrip.run(quick=args.quick, latency_s=args.latency),
        "fleet": run_fleet,
        "floor": lambda: floor.run(quick=args.quick, duration_s=args.duration, repeats=args.repeat),
        "writes": lambda: writes.run(quick=args.quick),
        "plantpage": lambda: plant_page.run(quick=args.quick),
        "opcua": lambda: opcua.run(quick=args.quick, machines=sizes[0] if sizes else None, duration_s=args.duration,
                                   repeats=args.repeat, diagnose=args.diagnose,
                                   modes=tuple(args.modes.split(",")) if args.modes else opcua.MODES,
                                   pin=args.pin, burn_cores=args.burn_cores, with_burst=not args.no_burst),
        "reload": lambda: reload.run(sizes=sizes, period_s=float(args.period) if args.period else None,
                                     duration_s=args.duration, quick=args.quick),
        "outage": lambda: outage.run(machines=sizes[0] if sizes else None,
                                     period_s=float(args.period) if args.period else None,
                                     outage_s=args.outage, duration_s=args.duration, quick=args.quick,
                                     outages=args.outages),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help=f"benchmarks to run: {', '.join(BENCHMARKS)} (default all but opcua)")
    parser.add_argument("--quick", action="store_true", help="small sizes and short runs (a smoke run)")
    parser.add_argument("--repeat", type=int, default=2, help="repeat each fleet size this often (default 2)")
    parser.add_argument("--sizes", default="", help="fleet sizes, comma separated (default 10,50,100,200)")
    parser.add_argument("--duration", type=float, default=None, help="fleet measuring window, seconds")
    parser.add_argument("--period", default="", metavar="SECONDS",
                        help="fleet: poll period of every machine, seconds; comma separated for several (default 0.1)")
    parser.add_argument("--warmup", type=float, default=None,
                        help="fleet: seconds between the last birth and the window (default 10)")
    parser.add_argument("--outage", type=float, default=None, metavar="SECONDS",
                        help="outage: how long the broker stays down (default 60)")
    parser.add_argument("--outages", type=int, default=1, metavar="N",
                        help="outage: this many outages in one daemon's life, a row each (default 1)")
    parser.add_argument("--latency", type=float, default=roundtrip.LATENCY_S,
                        help="simulated per-request latency for roundtrip, seconds (default 0.002)")
    parser.add_argument("--spy", default="", metavar="FILE",
                        help="fleet: record py-spy collapsed stacks of the daemon during the window into FILE "
                             "(the largest size wins); summarise with python -m bench.profile_summary FILE")
    parser.add_argument("--tracemalloc", default="", metavar="FILE",
                        help="fleet: run the daemon under tracemalloc and write its live allocations by module "
                             "at the end of the window into FILE (the largest size's first run; CPU figures "
                             "of that run include tracemalloc's cost); summarise with python -m bench.memory_summary")
    parser.add_argument("--modes", default="", metavar="MODES",
                        help=f"opcua: modes to run, comma separated, off among them ({', '.join(opcua.ALL_MODES)}; "
                             "default off,thread,loop)")
    parser.add_argument("--pin", action="store_true",
                        help="opcua: the daemon on CPU 0, every other process of the rig (simulators, broker, MQTT "
                             "subscriber, OPC UA client) on CPU 1, in every mode (bench.pinning)")
    parser.add_argument("--burn-cores", type=float, default=opcua.BURN_CORES, metavar="CORES",
                        help=f"opcua: what mode burn's burner takes, share of one CPU (default {opcua.BURN_CORES})")
    parser.add_argument("--no-burst", action="store_true",
                        help="opcua: skip the 10,000-item burst after each window (shorter runs)")
    parser.add_argument("--diagnose", action="store_true",
                        help="fleet and opcua: run the daemon with bench.latency_daemon's probes (loop lag, GC "
                             "pauses, grid slots, stamp to outputs) and add their figures to each row")
    parser.add_argument("--same-plan", action="store_true",
                        help="fleet: servo loads every 10th and counters every 100th tick at any period (as at 10 Hz), "
                             "so CPU per cycle compares the same reads across periods")
    parser.add_argument("--same-clock", action="store_true",
                        help="fleet: every simulated CNC clock is this host's (an NTP-synced plant), not each its own "
                             "offset and phase within the second (bench.clocks)")
    parser.add_argument("--py-spy", default="py-spy", help="the py-spy executable")
    parser.add_argument("--results", type=Path, default=None, help="directory for JSON results")
    args = parser.parse_args(argv)
    names = args.names or list(DEFAULT)
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        parser.error(f"unknown benchmark(s) {unknown}; expected some of {', '.join(BENCHMARKS)}")
    machine = machine_info()
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']}, "
          f"load {machine['loadavg_1m']}", flush=True)
    table = runners(args)
    failed = False
    for name in names:
        try:
            result = table[name]()
        except Exception:
            traceback.print_exc()
            result = Result(name, "python -m bench " + name, status="failed",
                            notes=[traceback.format_exc().strip().splitlines()[-1]])
            failed = True
        print(render(result), flush=True)
        path = save(result, machine, args.results) if args.results else save(result, machine)
        print(f"saved {path}\n", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
