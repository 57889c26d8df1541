"""A poll tick's Python cost without I/O: recorded CNC answers replayed to real pollers, DDATA encoded.

    python -m bench.tickreplay record FILE [--period 0.1] [--seconds 60] [--same-plan]
    python -m bench.tickreplay replay FILE [--machines 100] [--rounds 1] [--digest] [--profile OUT] [--per-tick OUT]
    python -m bench.tickreplay explain PER_TICK_FILE...

`record` polls one simulated CNC (the fleet workload) for a while and keeps every request's answer frame
and the poll times of every tick. `replay` gives each of N pollers its own client whose round trip hands
back the recorded answer to the same request bytes (no socket, no waiting), runs the recorded ticks
round-robin over the N machines and encodes each tick's changes as Sparkplug DATA, as the daemon does.
CPU per tick is the collector's and encoder's Python work; N spreads it over N machines' objects, as a
fleet does (cache misses included, loop and kernel excluded). For A/B of changes to the tick path.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import cProfile
import gc
import hashlib
import json
import pickle
import tempfile
import time
import types
from operator import is_not
from pathlib import Path
from typing import Any

from bench.floor import DroppingSink
from bench.procs import SimProcess
from bench.workload import CLOCK_MACRO, STAMP_MACRO, machines_section
from edge.collect import plan as pl
from edge.collect import poller as poller_module
from edge.collect.changes import ChangeDetector
from edge.collect.plant_state import SPECS as PLANT_STATE_SPECS
from edge.collect.poller import MachinePoller
from edge.collect.tickgrid import TickGrid
from edge.config import parse_config
from edge.focas.client import FocasClient
from edge.focas.frame import Frame
from edge.focas.function_entry import Context
from edge.publish import mqtt_wire
from edge.publish.aliases import AliasMap
from edge.publish.forwarding import Outbox
from edge.publish.node import SparkplugNode
from edge.service.gc_tuning import tune_collector
from edge.service.settings import machine_settings


async def begin_session(poller: MachinePoller, node: SparkplugNode) -> pl.MachinePlan:
    """What the poller does between connect and its first tick, for a replayed session: the static reads, the
    plan, fresh change detection and clock, and the device's DBIRTH (the replays share it)."""
    static = await poller._read_static()
    plan = pl.MachinePlan.build(poller.machine.poll, static)
    poller._full_plan = poller._plan = plan
    poller._changes = ChangeDetector(plan.deadbands(), [spec.name for spec in poller._birth_specs(plan)])
    poller._last_raw = [poller_module._NOTHING] * len(plan.reads)
    poller._clock.new_session()
    node.device_online(poller.machine_id, [*plan.metrics(), poller_module.DROPPED_FUNCTIONS, *PLANT_STATE_SPECS], [])
    return plan



def _config(period: float, ports: list[int], same_plan: bool = False) -> Any:
    return parse_config(f"mqtt: {{host: 127.0.0.1, sparkplug: {{group_id: bench, edge_node_id: gw}}}}\n"
                        f"machines:\n{machines_section(ports, period, same_plan)}", "replay", {})


async def _record(period: float, seconds: float, same_plan: bool = False) -> dict[str, Any]:
    sim = SimProcess(1, stamp_macro=STAMP_MACRO, clock_macro=CLOCK_MACRO)
    frames: list[tuple[bytes, Frame]] = []
    ticks: list[tuple[frozenset[pl.Group], list[float]]] = []
    original_roundtrip = FocasClient._roundtrip
    original_tick = MachinePoller._tick

    async def roundtrip(self: FocasClient, data: bytes, expected: Any, what: str) -> Frame:
        frame = await original_roundtrip(self, data, expected, what)
        frames.append((data, frame))
        return frame

    async def tick(self: MachinePoller, plan: pl.MachinePlan, groups: Any) -> Any:
        real = time.time
        stamps: list[float] = []

        def clock() -> float:
            stamps.append(real())
            return stamps[-1]

        mono_real = time.monotonic

        def mono() -> float:
            stamps.append(mono_real())
            return stamps[-1]

        poller_module.time = types.SimpleNamespace(time=clock, monotonic=mono)  # type: ignore[assignment]
        try:
            return await original_tick(self, plan, groups)
        finally:
            poller_module.time = time  # type: ignore[assignment]
            ticks.append((frozenset(groups), stamps))

    FocasClient._roundtrip = roundtrip  # type: ignore[method-assign]
    MachinePoller._tick = tick  # type: ignore[method-assign]
    try:
        config = _config(period, sim.ports, same_plan)
        with tempfile.TemporaryDirectory() as state:
            poller = MachinePoller(machine_settings(config, config.machines[0]), DroppingSink(), Path(state),
                                   jitter_s=0.0, grid=TickGrid(config.poll_grid_step_s))
            task = asyncio.create_task(poller.run())
            await asyncio.sleep(seconds)
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            sysinfo = poller.session.sysinfo
            await poller.close()
    finally:
        FocasClient._roundtrip = original_roundtrip  # type: ignore[method-assign]
        MachinePoller._tick = original_tick  # type: ignore[method-assign]
        sim.stop()
    return {"period": period, "frames": frames, "ticks": ticks, "sysinfo": sysinfo, "same_plan": same_plan}


class _Replayed:
    """The `time` module as _tick sees it: the recorded values of one tick, in call order."""

    def __init__(self) -> None:
        self.values: collections.deque[float] = collections.deque()
        self.last = 0.0

    def _next(self) -> float:
        if self.values:
            self.last = self.values.popleft()
        return self.last

    def time(self) -> float:
        return self._next()

    def monotonic(self) -> float:
        return self._next()


async def _replay(recording: dict[str, Any], machines: int, rounds: int, gc_mode: str,
                  digest: bool = False, profile_to: Path | None = None, per_tick: bool = False) -> dict[str, Any]:
    answers: dict[bytes, list[Frame]] = collections.defaultdict(list)
    for data, frame in recording["frames"]:
        answers[data].append(frame)
    config = _config(recording["period"], [8193] * machines, recording.get("same_plan", False))
    node = SparkplugNode("bench", "gw", AliasMap())
    node.session_started(0)
    node.born = True
    outbox = Outbox()
    topics = mqtt_wire.TopicCache(v5=True)
    sent: list[bytes] = []
    clock = _Replayed()
    published = hashlib.sha256()  # every published (machine, name, value, type, timestamp, quality), in order

    with tempfile.TemporaryDirectory() as state:
        pollers = []
        for machine in config.machines:
            poller = MachinePoller(machine_settings(config, machine), DroppingSink(), Path(state), jitter_s=0.0)
            client = poller.session
            assert isinstance(client, FocasClient)
            positions: dict[bytes, int] = collections.defaultdict(int)

            async def roundtrip(data: bytes, expected: Any, what: str,
                                positions: dict[bytes, int] = positions) -> Frame:
                recorded = answers[data]
                frame = recorded[positions[data] % len(recorded)]
                positions[data] += 1
                return frame

            client._roundtrip = roundtrip  # type: ignore[method-assign]
            client.sysinfo = recording["sysinfo"]
            client.context = Context.from_sysinfo(recording["sysinfo"])
            client._connected = True
            pollers.append((poller, await begin_session(poller, node)))

        def publish(device_id: str, samples: Any) -> None:
            for message in node.device_data(device_id, samples):
                prefix = topics.prefix(message.topic, message.retain)
                assert prefix is not None
                sent.append(mqtt_wire.publish_packet(prefix, message.payload))
            outbox.add(device_id, "data", samples)
            if digest:
                for s in samples:
                    published.update(repr((device_id, s.name, s.value, s.type.value, s.timestamp_ms,
                                           int(s.quality))).encode())

        ticks = recording["ticks"]
        if gc_mode == "off":
            gc.disable()
        elif gc_mode in ("daemon", "refreeze"):
            tune_collector()
        elif gc_mode.startswith("young="):
            tune_collector()
            gc.set_threshold(int(gc_mode[6:]), *gc.get_threshold()[1:])
        poller_module.time = clock  # type: ignore[assignment]
        profiler = cProfile.Profile() if profile_to is not None else None
        rows: list[list[float]] = []
        times: list[float] = []
        try:
            for run in range(rounds + 1):  # round 0 warms up (first answers, births)
                count = samples = 0
                if run == 1 and profiler is not None:
                    profiler.enable()
                cpu = time.process_time()
                for groups, stamps in ticks:
                    for poller, plan in pollers:
                        clock.values.extend(stamps)
                        if per_tick and run:
                            reading, before = poller._clock._reading, list(poller._last_raw)
                            began = time.perf_counter_ns()
                        tick = await poller._tick(plan, groups)
                        if tick.samples:
                            publish(poller.machine_id, tick.samples)
                            samples += len(tick.samples)
                        if per_tick and run:
                            took = time.perf_counter_ns() - began
                            moved = sum(map(is_not, poller._last_raw, before))
                            times.append(took / 1000)
                            rows.append(tick_features(groups, len(tick.samples), moved,
                                                      poller._clock._reading is not reading))
                        count += 1
                    if len(sent) >= 1000:  # a barrier a second, at 1,000 machine-cycles a second
                        sent.clear()
                        outbox.confirm(outbox.mark())
                cpu = time.process_time() - cpu
                if run == 0 and gc_mode == "refreeze":
                    gc.collect()
                    gc.freeze()
                if run:
                    print(f"round {run}: {machines} machines, {count} ticks, {samples / count:.2f} samples/tick, "
                          f"{cpu / count * 1e6:.1f} us/tick")
        finally:
            poller_module.time = time  # type: ignore[assignment]
            if profiler is not None and profile_to is not None:
                profiler.disable()
                profiler.dump_stats(profile_to)
        if per_tick:
            print_cost_model(rows, times)
        if digest:
            print(f"digest of the published samples: {published.hexdigest()}")
    return {"period": recording["period"], "machines": machines, "features": FEATURES, "rows": rows, "us": times}


FEATURES = ("fixed", "published value", "moved read", "servo loads read", "counters read", "new clock second")


def tick_features(groups: Any, samples: int, moved: int, news: bool) -> list[float]:
    """What one replayed tick did, as FEATURES (the columns of the cost model)."""
    return [1.0, float(samples), float(moved), float(pl.Group.LOADS in groups), float(pl.Group.COUNTERS in groups),
            float(news)]


def fit_cost_model(rows: list[list[float]], times: list[float]) -> dict[str, float]:
    """Least squares of each tick's time over its FEATURES. A feature that never varies gets no column, nor
    does one the ticks cannot tell apart from the features before it (in a short recording two features may
    move together on every tick): its time goes to those."""
    used = [j for j in range(len(FEATURES)) if j == 0 or len({row[j] for row in rows}) > 1]
    a = [[sum(r[i] * r[j] for r in rows) for j in used] for i in used]
    b = [sum(r[i] * t for r, t in zip(rows, times, strict=True)) for i in used]
    m = len(used)
    tiny = 1e-9 * max((abs(a[i][i]) for i in range(m)), default=1.0)
    pivots: list[tuple[int, int]] = []  # (row, column) of each column that gets a coefficient
    for col in range(m):  # Gauss-Jordan on the normal equations (a handful of columns)
        row = len(pivots)
        pivot = max(range(row, m), key=lambda r: abs(a[r][col]), default=row)
        if pivot >= m or abs(a[pivot][col]) <= tiny:
            continue  # a combination of the columns before it: no coefficient of its own
        a[row], a[pivot], b[row], b[pivot] = a[pivot], a[row], b[pivot], b[row]
        for r in range(m):
            if r != row:
                f = a[r][col] / a[row][col]
                a[r] = [x - f * y for x, y in zip(a[r], a[row], strict=True)]
                b[r] -= f * b[row]
        pivots.append((row, col))
    return {FEATURES[used[col]]: b[row] / a[row][col] for row, col in pivots}


def print_cost_model(rows: list[list[float]], times: list[float]) -> None:
    """The fit of fit_cost_model, each feature's share of the mean tick."""
    coefficients = fit_cost_model(rows, times)
    print(f"per-tick model over {len(rows)} ticks (mean {sum(times) / len(times):.1f} us a tick):")
    for name, c in coefficients.items():
        j = FEATURES.index(name)
        mean = sum(r[j] for r in rows) / len(rows)
        print(f"  {name:18} {c:7.2f} us x {mean:6.3f} a tick = {c * mean:6.1f} us")


def explain(files: list[Path]) -> None:
    """One fit over the per-tick files of several replays (same code, e.g. the 10 Hz and the 1 Hz recording at
    the same fleet size), then each file's mean tick split by feature: what makes one tick dearer than another."""
    loaded = [json.loads(f.read_text()) for f in files]
    rows = [row for d in loaded for row in d["rows"]]
    times = [t for d in loaded for t in d["us"]]
    coefficients = fit_cost_model(rows, times)
    print(f"one fit over {len(rows)} ticks of {len(files)} replays: "
          + ", ".join(f"{name} {c:.2f} us" for name, c in coefficients.items()))
    for f, d in zip(files, loaded, strict=True):
        n = len(d["rows"])
        means = {name: sum(r[FEATURES.index(name)] for r in d["rows"]) / n for name in coefficients}
        parts = ", ".join(f"{name} {means[name]:.3f} x {c:.2f} = {means[name] * c:.1f}"
                          for name, c in coefficients.items())
        print(f"{f.name} ({d['machines']} machines, period {d['period']:g} s): measured {sum(d['us']) / n:.1f} us "
              f"a tick, modelled {sum(means[k] * c for k, c in coefficients.items()):.1f}: {parts}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", choices=("record", "replay", "explain"))
    parser.add_argument("file", type=Path, nargs="+", help="explain: the --per-tick files of several replays")
    parser.add_argument("--period", type=float, default=0.1)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--machines", type=int, default=100)
    parser.add_argument("--same-plan", action="store_true",
                        help="record with loads and counters every 10th and 100th tick at any period (as at 10 Hz)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--gc", default="daemon",
                        help="collector settings: daemon (the daemon's), refreeze (and freeze after warming up), "
                             "young=N, default (CPython's), off")
    parser.add_argument("--digest", action="store_true",
                        help="print a digest of every published sample (the same in two trees: same output)")
    parser.add_argument("--profile", type=Path, metavar="OUT",
                        help="cProfile the replayed rounds (not the warm-up round) into OUT (pstats)")
    parser.add_argument("--per-tick", type=Path, metavar="OUT",
                        help="time every replayed tick, fit its time to what it did (bench.tickreplay.FEATURES) "
                             "and write the ticks to OUT (JSON) for a fit over several recordings")
    args = parser.parse_args()
    if args.mode == "explain":
        explain(args.file)
        return
    args.file = args.file[0]
    if args.mode == "record":
        recording = asyncio.run(_record(args.period, args.seconds, args.same_plan))
        args.file.write_bytes(pickle.dumps(recording))
        print(f"recorded {len(recording['ticks'])} ticks, {len(recording['frames'])} frames")
    else:
        ticks = asyncio.run(_replay(pickle.loads(args.file.read_bytes()), args.machines, args.rounds, args.gc,
                                    args.digest, args.profile, args.per_tick is not None))
        if args.per_tick is not None:
            args.per_tick.write_text(json.dumps(ticks))


if __name__ == "__main__":
    main()
