"""The daemon under tracemalloc: `python -m bench.memory_daemon CONFIG OUT.json` (SIGUSR1 writes, SIGTERM stops).

Where a gateway's memory goes is a question of which module allocated the live objects, not of RSS alone:
each SIGUSR1 writes the live Python allocations grouped by module (edge.*, a third-party package, or the
standard library) and the top allocation sites to OUT.json. tracemalloc costs CPU and memory of its own,
so the fleet figures of a run with it are not the fleet's figures.

The dump also says how much of it was cyclic garbage: after the first snapshot, everything is unfrozen and
collected (edge.service.gc_tuning freezes what survives the young collections, so a cycle that outlives
one waits for the hourly full collection), and the second snapshot's total is `after_full_collection`.
A dump ends the run's measuring: the collection changes what the daemon holds.
"""

from __future__ import annotations

import gc
import json
import signal
import sys
import sysconfig
import tracemalloc
from collections import defaultdict
from pathlib import Path
from types import FrameType
from typing import Any

from edge.service.daemon import run_daemon

REPO = Path(__file__).resolve().parent.parent
STDLIB = Path(sysconfig.get_paths()["stdlib"]).resolve()
TOP_SITES = 40


def module_of(filename: str) -> str:
    """edge.publish.ddata, paho, asyncio, <frozen ...>: the owner of a file, at the depth that names it."""
    if filename.startswith("<"):
        return filename
    path = Path(filename).resolve()
    for marker in ("site-packages", "dist-packages"):
        if marker in path.parts:
            return path.parts[path.parts.index(marker) + 1].removesuffix(".py")
    if path.is_relative_to(REPO):
        return ".".join(path.relative_to(REPO).with_suffix("").parts)
    if path.is_relative_to(STDLIB):
        parts = path.relative_to(STDLIB).with_suffix("").parts
        return "stdlib." + parts[0]
    return str(path)


def breakdown(snapshot: tracemalloc.Snapshot) -> dict[str, Any]:
    """Live bytes and blocks per module and per allocation site (file:line), largest first."""
    by_module: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for stat in snapshot.statistics("filename"):
        entry = by_module[module_of(stat.traceback[0].filename)]
        entry[0] += stat.size
        entry[1] += stat.count
    sites = [{"site": f"{module_of(s.traceback[0].filename)}:{s.traceback[0].lineno}", "bytes": s.size,
              "blocks": s.count} for s in snapshot.statistics("lineno")[:TOP_SITES]]
    ordered = sorted(by_module.items(), key=lambda item: -item[1][0])
    modules = [{"module": m, "bytes": b, "blocks": c} for m, (b, c) in ordered]
    total = sum(b for b, _ in by_module.values())
    return {"total_bytes": total, "modules": modules, "sites": sites}


def main() -> int:
    config, out = Path(sys.argv[1]), Path(sys.argv[2])
    tracemalloc.start(1)

    def dump(signum: int, frame: FrameType | None) -> None:
        found = breakdown(tracemalloc.take_snapshot())
        gc.unfreeze()
        found["collected_objects"] = gc.collect()
        after = breakdown(tracemalloc.take_snapshot())
        found["after_full_collection"] = {"total_bytes": after["total_bytes"], "modules": after["modules"]}
        out.write_text(json.dumps(found, indent=1))

    signal.signal(signal.SIGUSR1, dump)
    return run_daemon(config)


if __name__ == "__main__":
    sys.exit(main())
