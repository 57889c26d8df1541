"""The soak child's memory probe (SOAK_MEMORY_DIR): where an RSS step comes from, live objects or the heap.

Each SIGUSR1 writes `probe-N.txt` to the directory: the C heap's figures (glibc mallinfo2: bytes in use,
free inside the heap, mmapped); with SOAK_MEMORY_TRACE=1, from the second signal on, also the Python
allocations still alive that were made since the first signal (tracemalloc starts at the first), the top
lines by size and by growth against the previous probe. Every report line goes to `reports.jsonl` too. A
step the heap's free bytes explain is memory glibc keeps, not a leak; one outside the C heap (RSS minus
its arena) is Python's own small-object arenas. tracemalloc costs CPU: at 1,000 machines it slows the
daemon until CNC sessions time out, so it is off unless asked for."""

from __future__ import annotations

import ctypes
import logging
import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]


def heap() -> dict[str, int]:
    """glibc's heap figures in bytes ({} where there is no mallinfo2)."""
    try:
        function = ctypes.CDLL(None).mallinfo2
    except (OSError, AttributeError):
        return {}
    function.restype = _MallInfo2
    info = function()
    return {"heap_arena": info.arena, "heap_used": info.uordblks, "heap_free": info.fordblks,
            "heap_mmapped": info.hblkhd, "heap_top_pad": info.keepcost}


def rss() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


class MemoryProbe:
    def __init__(self, directory: Path) -> None:
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        self.count = 0
        self.previous: tracemalloc.Snapshot | None = None
        # tracemalloc at 1,000 machines slows the daemon until its CNC sessions time out: only on request
        self.trace = os.environ.get("SOAK_MEMORY_TRACE") == "1"
        self.reports = (directory / "reports.jsonl").open("a", buffering=1)

    def probe(self) -> None:
        started = time.perf_counter()
        lines = [f"probe {self.count} at {time.time():.1f}: rss {rss() / 1e6:.1f} MB, maxrss "
                 f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.1f} MB, python blocks "
                 f"{sys.getallocatedblocks()}"]
        lines += [f"  {k} {v / 1e6:.1f} MB" for k, v in heap().items()]
        if not self.trace:
            pass
        elif not tracemalloc.is_tracing():
            tracemalloc.start(1)
        else:
            snapshot = tracemalloc.take_snapshot().filter_traces(
                [tracemalloc.Filter(False, tracemalloc.__file__)])
            traced, peak = tracemalloc.get_traced_memory()
            lines.append(f"  traced (since probe 0) {traced / 1e6:.1f} MB, peak {peak / 1e6:.1f} MB")
            lines.append("  top live since probe 0, by line:")
            lines += [f"    {s}" for s in snapshot.statistics("lineno")[:25]]
            if self.previous is not None:
                lines.append("  growth against the previous probe, by line:")
                lines += [f"    {s}" for s in snapshot.compare_to(self.previous, "lineno")[:25]]
            self.previous = snapshot
        if self.count == 3:  # the last probe of bench outage: what malloc_trim gives back
            trimmed = ctypes.CDLL(None).malloc_trim(0)
            lines.append(f"  after malloc_trim(0) (returned {trimmed}): rss {rss() / 1e6:.1f} MB")
            lines += [f"  {k} {v / 1e6:.1f} MB" for k, v in heap().items()]
        lines.append(f"  probe took {time.perf_counter() - started:.2f} s")
        (self.directory / f"probe-{self.count}.txt").write_text("\n".join(lines) + "\n")
        self.count += 1


def from_environment() -> MemoryProbe | None:
    """The probe when SOAK_MEMORY_DIR names a directory; then edge.publish also logs INFO, with times."""
    directory = os.environ.get("SOAK_MEMORY_DIR")
    if not directory:
        return None
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("edge.publish").setLevel(logging.INFO)
    return MemoryProbe(Path(directory))
