"""Live Python objects per machine of N replaying pollers: `python -m bench.memory_replay REC [--machines 100]`.

The fleet's `--tracemalloc` gives the whole daemon's figure but needs the simulators, a broker and the
benchmark lock's minutes; this is bench.tickreplay (recorded answers, no I/O) under tracemalloc, its
snapshot taken after the last round while the pollers are alive, grouped by module (bench.memory_daemon's
grouping). It also prints a digest of every published sample, so a change that saves memory can show it
publishes the same. REC is what `python -m bench.tickreplay record` wrote (`--period 1` for the 1 s fleet).
The replay's own fixed parts (the held batches, the last packets) are divided by N too: use N >= 100.

The snapshot is taken where tickreplay prints its last round's line (its `print` is wrapped), which leaves
tickreplay itself as it is.
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import pickle
import tracemalloc
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench import tickreplay
from bench.memory_daemon import breakdown
from edge.publish.node import SparkplugNode
from edge.samples import Sample


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--machines", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--top", type=int, default=20)
    args = parser.parse_args(argv)
    published = hashlib.sha256()
    device_data = SparkplugNode.device_data

    def digesting(node: SparkplugNode, device_id: str, samples: Sequence[Sample]) -> Any:
        for s in samples:
            published.update(repr((device_id, s.name, s.value, s.type.value, s.timestamp_ms,
                                   int(s.quality))).encode())
        return device_data(node, device_id, samples)

    rounds_seen = 0

    def on_round(*line: Any) -> None:
        nonlocal rounds_seen
        print(*line)
        rounds_seen += 1
        if rounds_seen == args.rounds:
            _report(breakdown(tracemalloc.take_snapshot()), args.machines, args.top)

    SparkplugNode.device_data = digesting  # type: ignore[method-assign]
    tickreplay.print = on_round  # type: ignore[attr-defined]
    recording = pickle.loads(args.file.read_bytes())
    tracemalloc.start(1)
    try:
        asyncio.run(tickreplay._replay(recording, args.machines, args.rounds, "daemon"))
    finally:
        tracemalloc.stop()
        SparkplugNode.device_data = device_data  # type: ignore[method-assign]
        del tickreplay.print  # type: ignore[attr-defined]
    print(f"digest of the published samples: {published.hexdigest()}")


def _report(found: dict[str, Any], machines: int, top: int) -> None:
    print(f"live Python allocations: {found['total_bytes'] / machines / 1e3:.1f} kB per machine")
    for row in found["modules"][:top]:
        print(f"  {row['module']:<40} {row['bytes'] / machines:9,.0f} B/machine")


if __name__ == "__main__":
    main()
