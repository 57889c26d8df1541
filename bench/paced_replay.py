"""The fleet's ticks at their real pace without sockets: where a sample's time in the gateway goes.

    python -m bench.paced_replay FILE [--machines 1000] [--seconds 30] [--rtt 0.002] [--gc keeper]
                                      [--period P] [--grid STEP]

FILE is a `python -m bench.tickreplay record` recording. N pollers wake on the daemon's TickGrid at the
recorded period, their start phases spread as the daemon spreads them; each round trip hands back the
recorded answer to the same request bytes `--rtt` after it was sent (a timer: no simulator, no broker,
no kernel). Each tick's changes are encoded as Sparkplug DATA as the daemon does. Measured over the window:
answer -> DATA encoded per tick (the gateway's own queueing: a slot's burst, loop lag, GC pauses), how far
the moment a tick is stamped for lies from the moment the CNC answered (half the round trip after the
send), the loop's lag, every collection's pause, and CPU per tick. One process on one core: a loaded
host shows only as the lag it causes, which the 1,000-machine fleet run (21 processes) cannot separate.

The recording's CNC clock repeats every recording length, which the clock tracker would take for clock
steps: the replayed clock answers are not observed, so stamps are gateway time (where a tick is stamped
for is still measured). Log lines below ERROR are dropped.

--gc: `daemon` (start-up's freeze and young threshold, as main had), `settle` (and the machines' objects
frozen once born), `keeper` (the daemon's now: edge.service.gc_tuning.CollectorKeeper, which also runs the
young and middle collections by the clock).
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import logging
import pickle
import random
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.floor import DroppingSink
from bench.latency_daemon import Window, lag_probe, watch_collector, watch_grid
from bench.tickreplay import begin_session
from bench.workload import machines_section
from edge.collect import plan as pl
from edge.collect.poller import MachinePoller
from edge.collect.tickgrid import TickGrid
from edge.config import parse_config
from edge.focas.client import FocasClient
from edge.focas.frame import Frame
from edge.focas.function_entry import Context
from edge.publish import mqtt_wire
from edge.publish.aliases import AliasMap
from edge.publish.node import SparkplugNode
from edge.service.gc_tuning import CollectorKeeper, settle, tune_collector
from edge.service.settings import machine_settings

STARTS_PER_S = 200.0  # as the daemon spreads a fleet's first connects (edge.service.daemon)


class _Middle:
    """The stamp moment before edge.collect.answer_time: half of the whole span after the send."""

    def half_rtt(self, rtt_s: float) -> float:
        return rtt_s / 2

    def reset(self) -> None:
        pass


class PacedMachine:
    """One poller whose client answers from the recording after `rtt` seconds, with the times it saw."""

    def __init__(self, poller: MachinePoller, answers: dict[bytes, list[Frame]], rtt: float,
                 middle: bool = False) -> None:
        self.poller = poller
        if middle:  # stamp the middle of send-to-handled, as the poller did before edge.collect.answer_time
            poller._answer_time = _Middle()  # type: ignore[assignment]
        self.answered = 0.0  # when the CNC answered the latest request (half the round trip after the send)
        self.arrived = 0.0  # when its answer arrived
        self.stamped_at = 0.0  # the gateway moment the latest tick was stamped for
        positions: collections.Counter[bytes] = collections.Counter()

        async def roundtrip(data: bytes, expected: Any, what: str) -> Frame:
            sent = time.monotonic()
            await asyncio.sleep(rtt)
            self.answered, self.arrived = sent + rtt / 2, sent + rtt
            recorded = answers[data]
            positions[data] += 1
            return recorded[positions[data] % len(recorded)]

        client = poller.session
        assert isinstance(client, FocasClient)
        client._roundtrip = roundtrip  # type: ignore[method-assign]
        poller._clock.observe = lambda *args: False  # type: ignore[method-assign]
        stamp = poller.clock.source_time_ms

        def source_time_ms(gateway_monotonic: float, gateway_wall: float) -> int:
            self.stamped_at = gateway_monotonic
            return stamp(gateway_monotonic, gateway_wall)

        poller.clock.source_time_ms = source_time_ms  # type: ignore[method-assign]


async def _paced(recording: dict[str, Any], machines: int, seconds: float, rtt: float, gc_mode: str,
                 warmup: float, grid_s: float | None = None, period_s: float | None = None,
                 middle: bool = False) -> dict[str, Any]:
    answers: dict[bytes, list[Frame]] = collections.defaultdict(list)
    for data, frame in recording["frames"]:
        answers[data].append(frame)
    period = period_s or recording["period"]
    # Another period than the recording's: loads and counters every 10th and 100th tick as at 10 Hz
    # (bench.workload's same plan), so a 10 Hz recording's request shapes are the ones asked at any pace.
    config = parse_config(f"mqtt: {{host: 127.0.0.1, sparkplug: {{group_id: bench, edge_node_id: gw}}}}\n"
                          f"machines:\n{machines_section([8193] * machines, period, period != recording['period'])}",
                          "replay", {})
    grid = TickGrid(grid_s or config.poll_grid_step_s)
    node = SparkplugNode("bench", "gw", AliasMap())
    node.session_started(0)
    node.born = True
    topics = mqtt_wire.TopicCache(v5=True)
    window = Window()
    recording_window = [False]
    stamp_offsets: list[float] = []  # stamped moment minus the CNC's answer moment
    tune_collector()
    with tempfile.TemporaryDirectory() as state:
        fleet = []
        for machine in config.machines:
            poller = MachinePoller(machine_settings(config, machine), DroppingSink(), Path(state), grid=grid)
            client = poller.session
            assert isinstance(client, FocasClient)
            client.sysinfo = recording["sysinfo"]
            client.context = Context.from_sysinfo(recording["sysinfo"])
            client._connected = True
            fleet.append(PacedMachine(poller, answers, rtt, middle))

        async def run(machine: PacedMachine) -> None:
            await asyncio.sleep(random.uniform(0, max(1.0, machines / STARTS_PER_S)))
            poller = machine.poller
            plan = await begin_session(poller, node)
            schedule = pl.Schedule(plan.periods)
            schedule.start(time.monotonic())
            schedule.due(time.monotonic())
            while True:
                await grid.sleep_until(schedule.next_due() or time.monotonic() + period)
                groups = schedule.due(time.monotonic())
                if not groups:
                    continue
                started = time.monotonic()
                tick = await poller._tick(plan, groups)
                for message in node.device_data(poller.machine_id, tick.samples) if tick.samples else ():
                    prefix = topics.prefix(message.topic, message.retain)
                    assert prefix is not None
                    mqtt_wire.publish_packet(prefix, message.payload)
                if recording_window[0]:
                    done = time.monotonic()
                    window.tick.append(done - started)
                    window.publish_lag.append(done - machine.arrived)
                    stamp_offsets.append(machine.stamped_at - machine.answered)

        tasks = [asyncio.create_task(run(machine)) for machine in fleet]
        watch_collector(window)
        watch_grid(window, grid)
        lag = asyncio.create_task(lag_probe(window))
        await asyncio.sleep(max(1.0, machines / STARTS_PER_S) + 2 * period)  # every machine started
        if gc_mode == "settle":
            frozen, held = settle()
            print(f"settled: {frozen} objects frozen, loop held {held * 1000:.0f} ms")
        elif gc_mode == "keeper":
            keeper = CollectorKeeper(lambda: True)
            keeper.machines_started()
            tasks.append(asyncio.create_task(keeper.run()))
        await asyncio.sleep(warmup)
        window.reset()
        recording_window[0] = True
        cpu = time.process_time()
        await asyncio.sleep(seconds)
        cpu = time.process_time() - cpu
        recording_window[0] = False
        report = window.report()
        for task in [*tasks, lag]:
            task.cancel()
        await asyncio.gather(*tasks, lag, return_exceptions=True)
    offsets = sorted(abs(o) for o in stamp_offsets)
    report["stamp_moment_abs"] = {"p50_ms": statistics.median(offsets) * 1000 if offsets else None,
                                  "p99_ms": offsets[int(0.99 * len(offsets))] * 1000 if offsets else None}
    report["cpu_us_per_tick"] = cpu / len(window.tick) * 1e6 if window.tick else None
    report["ticks_per_s"] = len(window.tick) / seconds
    report["machines"], report["period_s"], report["gc_mode"], report["rtt_s"] = machines, period, gc_mode, rtt
    report["grid_step_s"] = grid.step_s
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--machines", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--warmup", type=float, default=10.0)
    parser.add_argument("--rtt", type=float, default=0.002)
    parser.add_argument("--gc", default="keeper", choices=("daemon", "settle", "keeper"))
    parser.add_argument("--grid", type=float, default=None, help="poll grid step, seconds (default: the config's auto)")
    parser.add_argument("--period", type=float, default=None,
                        help="poll period, seconds (default the recording's; another one polls the same plan per "
                             "tick: a 10 Hz recording at 1 s is 100 x 10 Hz's work per tick at 1,000 x 1 Hz's pace)")
    parser.add_argument("--stamp-middle", action="store_true",
                        help="stamp ticks at the middle of send-to-handled (the poller before answer_time)")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    report = asyncio.run(_paced(pickle.loads(args.file.read_bytes()), args.machines, args.seconds, args.rtt,
                                args.gc, args.warmup, args.grid, args.period, args.stamp_middle))
    text = json.dumps(report, indent=1)
    if args.out is not None:
        args.out.write_text(text)
    summary = {k: report[k] for k in ("machines", "period_s", "gc_mode", "grid_step_s", "cpu_us_per_tick",
                                      "ticks_per_s")}
    print(json.dumps(summary))
    print(f"loop thread ran {report['loop_thread_ran_s']:.1f} s, waited for a CPU "
          f"{report['loop_thread_waited_s']:.1f} s of {report['window_s']:.1f} s")
    for key in ("publish_lag", "tick", "loop_lag", "grid_timer_late", "stamp_moment_abs", "machines_per_slot"):
        name = "answer_to_encoded" if key == "publish_lag" else key
        print(f"{name}: {json.dumps(report[key] if key != 'publish_lag' else report['stamp_to_outputs'])}")
    print(f"gc: {json.dumps(report['gc'])}; tracked {report['gc_tracked_objects']}, "
          f"frozen {report['gc_frozen_objects']}")


if __name__ == "__main__":
    main()
