"""The CNC clock's work per poll tick, alone: N machines' ClockFeeds driven at 1 Hz without I/O.

    python -m bench.clockpath [--machines 500] [--seconds 40] [--warmup 120]

Each tick does what the poller does with the tick's clock answer (edge.collect.poller): `ClockFeed.observe`,
the sample timestamp (`source_time_ms`), the Clock/* metrics (`ClockFeed.samples`) and the probe plan
(`ClockProbes.send_at`); a clock-only read the plan asks for before the next tick is done at its moment. At 1 Hz
every tick reads a new CNC second, so this is the clock's per-second cost, the part of a 1 Hz tick the tick
replay (bench.tickreplay) covers only in part (it has no probe plan). The CNC clocks run 0.3 s ahead of the
gateway, the machines' phases spread over the second. Prints µs a tick (all of it, and `send_at` alone) and a
digest of every Clock/* value, stamp and planned send time: equal digests, equal behaviour (for A/B of changes).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import math
import time
from datetime import datetime, timedelta
from zoneinfo import ZoneInfo

from edge.collect.clock_feed import ClockFeed

HALF_RTT_S = 0.0008
BASE_WALL = 1_790_000_000.0
BASE_MONO = 1000.0


class _Fleet:
    def __init__(self, machines: int) -> None:
        zone = ZoneInfo("Europe/Berlin")
        self.feeds = [ClockFeed(f"m{i}", zone, 60.0) for i in range(machines)]
        self.start = datetime.fromtimestamp(BASE_WALL, zone).replace(tzinfo=None)
        self.seconds: dict[int, datetime] = {}  # one object per CNC second, as the client hands it back
        self.out: list[object] = []
        self.tick_s = self.send_at_s = 0.0
        self.probes = 0

    def report(self, name: str, value: object, kind: object, timestamp: int, quality: object = None) -> None:
        self.out.append((name, value, timestamp))
        return None  # nothing published: only the clock's own work is timed

    def cnc_at(self, machine: int, mono: float, second: int) -> tuple[datetime, float]:
        wall = BASE_WALL + (mono - BASE_MONO) + 0.0002 * math.sin(second)  # the gateway's wall clock wobbles
        cnc_second = math.floor(wall + 0.3 + machine * 0.0001 - BASE_WALL)
        value = self.seconds.get(cnc_second)
        if value is None:
            value = self.seconds[cnc_second] = self.start + timedelta(seconds=cnc_second)
        return value, wall

    def run(self, first: int, last: int) -> None:
        samples: list[object] = []
        perf = time.perf_counter
        for second in range(first, last):
            for machine, feed in enumerate(self.feeds):
                mono = BASE_MONO + second + (machine * 0.000731) % 1.0
                cnc, wall = self.cnc_at(machine, mono, second)
                started = perf()
                if feed.observe(cnc, mono, wall, HALF_RTT_S) or feed.news:
                    feed.samples(feed.tracker.source_time_ms(mono, wall), mono, self.report, samples)  # type: ignore[arg-type]
                planned = perf()
                send_at = feed.probes.send_at(mono + 0.0005, HALF_RTT_S, HALF_RTT_S)
                done = perf()
                self.tick_s += done - started
                self.send_at_s += done - planned
                self.out.append(send_at)
                if send_at < mono + 1.0:  # a clock-only read before the next tick
                    moment = send_at + HALF_RTT_S
                    cnc, wall = self.cnc_at(machine, moment, second)
                    feed.observe(cnc, moment, wall, HALF_RTT_S)
                    feed.probes.done(moment + HALF_RTT_S)
                    feed.news = True
                    self.probes += 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--machines", type=int, default=500)
    parser.add_argument("--seconds", type=int, default=40)
    parser.add_argument("--warmup", type=int, default=120, help="seconds before timing (the offsets narrow)")
    args = parser.parse_args()
    logging.disable(logging.CRITICAL)  # a thousand "using CNC time" lines are not the point
    fleet = _Fleet(args.machines)
    fleet.run(0, args.warmup)
    fleet.out.clear()
    fleet.tick_s = fleet.send_at_s = 0.0
    fleet.probes = 0
    fleet.run(args.warmup, args.warmup + args.seconds)
    ticks = args.machines * args.seconds
    digest = hashlib.sha256(repr(fleet.out).encode()).hexdigest()
    print(f"{fleet.tick_s / ticks * 1e6:.2f} us a tick, of which send_at {fleet.send_at_s / ticks * 1e6:.2f}; "
          f"{fleet.probes / args.machines / args.seconds * 60:.2f} clock-only reads a machine-minute")
    print(f"digest {digest}")


if __name__ == "__main__":
    main()
