"""The spool replay's CPU per row without a broker: `python -m bench.replay_cost [--machines 1000] [--rows 20000]`.

A 1,000-machine outage spools one row per machine per tick; the replay must send them at ten times the live
rate while the live ticks keep the loop busy, so its cost per row decides whether it can. This fills a real
DiskSpool with ticks of the fleet's shape (a dozen changed values of mixed types, one timestamp), records
every machine's birth values as the session does, and runs the real Replayer and DeliveryLink over a
connection that builds each PUBLISH packet (mqtt_wire, as the daemon's fast path) and acknowledges every
barrier at once, paced at 12 rows a machine a second (a 1 s fleet's backlog at the replay's 12x). Printed:
CPU per row and per value (not the pace's sleeps), messages and bytes sent. For A/B of the replay path.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from edge.publish import mqtt_wire
from edge.publish.aliases import AliasMap
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.holding import SpoolWriter
from edge.publish.link import DeliveryLink
from edge.publish.node import SparkplugNode
from edge.publish.replay import Replayer
from edge.publish.replay_dedupe import DeliveredValues
from edge.publish.spool import DiskSpool
from edge.publish.state_store import StateStore
from edge.publish.tasks import BackgroundTasks
from edge.samples import MetricSpec, MetricType, Sample

REPLAY_X = 12  # the replay's pace: 12 times the fleet's live rows a second (one row a machine a second)
# One tick's changed values: positions and loads (doubles), counters and PMC bytes (ints), a mode string.
SHAPE = ([("Position/X", MetricType.DOUBLE), ("Position/Y", MetricType.DOUBLE), ("Position/Z", MetricType.DOUBLE),
          ("Feed", MetricType.DOUBLE), ("Spindle/Speed", MetricType.DOUBLE), ("Spindle/Load", MetricType.DOUBLE)]
         + [(f"Macro/{500 + i}", MetricType.DOUBLE) for i in range(3)]
         + [("Pmc/R100", MetricType.UINT8), ("Sequence", MetricType.INT32), ("Mode", MetricType.STRING)])


class PacketConn:
    """Connected; builds every QoS 0 packet as the fast path does (`keep`: and keeps the payloads); every
    barrier is acknowledged at once; the socket takes every byte at once."""

    connected = True
    held = 0

    def __init__(self, keep: bool = False) -> None:
        self._topics = mqtt_wire.TopicCache(v5=False)
        self.messages = 0
        self.bytes = 0
        self.kept: list[bytes] | None = [] if keep else None

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> bool:
        prefix = self._topics.prefix(topic, retain)
        assert prefix is not None
        self.bytes += len(mqtt_wire.publish_packet(prefix, payload))
        self.messages += 1
        if self.kept is not None:
            self.kept.append(payload)
        return True

    async def publish_confirmed(self, *args: Any, **kwargs: Any) -> None:
        return None


class NodeTarget:
    """The Sparkplug session's side of a replay, for one node whose devices are all online."""

    def __init__(self, node: SparkplugNode) -> None:
        self.node = node

    def replay_ready(self) -> bool:
        return True

    def replay_devices(self) -> list[str]:
        return self.node.device_ids()

    def replay_accepts(self, device_id: str) -> bool:
        return True

    def historical(self, entry: Any, samples: Any) -> Any:
        return self.node.historical_data(entry.device_id, samples)

    def historical_rows(self, entry: Any, rows: Any) -> Any:
        return self.node.historical_rows(entry.device_id, rows)


def _tick(t: int, i: int) -> list[Sample]:
    ts = 1_790_000_000_000 + t * 1000 + i % 1000
    out = []
    for n, (name, mtype) in enumerate(SHAPE):
        if mtype is MetricType.DOUBLE:
            value: object = float(t * 0.37 + n + i)
        elif mtype is MetricType.STRING:
            value = "MEM" if t % 2 else "AUTO"
        else:
            value = (t + n) % 200
        out.append(Sample(name, value, mtype, ts))
    return out


async def _run(machines: int, rows: int, workdir: Path) -> dict[str, float]:
    counters: Counter[str] = Counter()
    spool = DiskSpool(workdir / "spool.sqlite")
    node = SparkplugNode("bench", "gw", AliasMap(StateStore(workdir / "state")), clock=lambda: 1_790_000_000_000)
    node.session_started(1)
    delivered = DeliveredValues()
    for i in range(machines):
        node.device_online(f"m{i:04d}", [MetricSpec(n, t) for n, t in SHAPE], _tick(-1, i))
    node.births()
    record_birth = getattr(delivered, "record_birth", delivered.record)  # main before spool-fast: keys
    for i in range(machines):
        record_birth(f"m{i:04d}", _tick(-1, i))
    for r in range(rows):
        spool.hold("sparkplug", f"m{r % machines:04d}", "data", _tick(r // machines, r % machines))
    await asyncio.sleep(0)  # the turn's commit
    gc.collect()
    gc.freeze()  # as the daemon freezes its born machines (edge.service.gc_tuning): the replay's own garbage
    tasks = BackgroundTasks()
    link = DeliveryLink("sparkplug", SpoolWriter(spool, counters), counters,
                        ForwardingPolicy(replay_rows_per_s=REPLAY_X * machines), tasks, delivered)
    conn = PacketConn()
    link.attach(conn, "bench")  # type: ignore[arg-type]
    replayer = Replayer(link, NodeTarget(node), spool, counters, tasks, delivered)
    cpu, wall = time.process_time(), time.perf_counter()
    await replayer._replay_rows(conn, link.session)  # type: ignore[arg-type]
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    assert counters["replayed_rows"] == rows, counters
    spool.close()
    return {"cpu_us_per_row": cpu / rows * 1e6, "cpu_us_per_value": cpu / rows / len(SHAPE) * 1e6,
            "wall_s": wall, "messages": conn.messages, "bytes_per_row": conn.bytes / rows}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--machines", type=int, default=1000)
    parser.add_argument("--rows", type=int, default=20_000)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-replay-") as tmp:
        found = asyncio.run(_run(args.machines, args.rows, Path(tmp)))
    print(f"replay of {args.rows} rows ({args.machines} machines, {len(SHAPE)} values a row): "
          f"{found['cpu_us_per_row']:.1f} us CPU a row ({found['cpu_us_per_value']:.2f} us a value), "
          f"{found['messages']} messages, {found['bytes_per_row']:.0f} bytes a row, {found['wall_s']:.2f} s")


if __name__ == "__main__":
    main()
