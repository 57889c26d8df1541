"""The soak child's memory probe (SOAK_MEMORY_DIR): where an RSS step comes from, live objects or the heap.

Each SIGUSR1 writes `probe-N.txt` to the directory: the C heap's figures (glibc mallinfo2: bytes in use, free
inside the heap, mmapped), RSS by kind of mapping, pymalloc's arenas and the bytes of their live blocks, and
SQLite's own heap (page caches, prepared statements); with SOAK_MEMORY_TRACE=1, from the second signal on,
also the Python allocations still alive that were made since the first signal (tracemalloc starts at the
first), the top lines by size and by growth against the previous probe. Every report line goes to
`reports.jsonl` too. A step the heap's free bytes explain is memory glibc keeps, not a leak; one outside the C
heap (RSS minus its arena) is Python's own small-object arenas. tracemalloc costs CPU: at 1,000 machines it
slows the daemon until CNC sessions time out, so it is off unless asked for."""

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


def mappings() -> dict[str, int]:
    """Resident bytes by kind of mapping (/proc/self/smaps): glibc's main heap (brk), anonymous maps (Python's
    1 MiB arenas, glibc's mmapped blocks and thread arenas, thread stacks), the spool's -shm file, the rest."""
    out = {"rss_brk_heap": 0, "rss_anon": 0, "rss_shm": 0, "rss_files": 0}
    kind = "rss_files"
    try:
        text = Path("/proc/self/smaps").read_text()
    except OSError:
        return {}
    for line in text.splitlines():
        head = line.split(None, 6)
        if head and "-" in head[0] and len(head) >= 5 and ":" not in head[0]:
            name = head[5] if len(head) > 5 else ""
            kind = ("rss_brk_heap" if name == "[heap]" else "rss_shm" if name.endswith("-shm")
                    else "rss_anon" if not name or name.startswith("[") else "rss_files")
        elif line.startswith("Rss:"):
            out[kind] += int(line.split()[1]) * 1024
    return out


def pymalloc() -> dict[str, int]:
    """Python's small-object allocator: arenas mapped and bytes in live blocks (sys._debugmallocstats)."""
    import tempfile
    figures: dict[str, int] = {}
    with tempfile.TemporaryFile("w+") as tmp:
        saved = os.dup(2)
        try:
            sys.stderr.flush()
            os.dup2(tmp.fileno(), 2)
            sys._debugmallocstats()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        tmp.seek(0)
        for line in tmp:
            if line.startswith("# arenas allocated current"):
                figures["py_arenas"] = int(line.split("=")[1].replace(",", "")) * 1024 * 1024
            elif line.startswith("# bytes in allocated blocks"):
                figures["py_used"] = int(line.split("=")[1].replace(",", ""))
    return figures


def sqlite_memory() -> dict[str, int]:
    """Bytes SQLite has malloc'd now and at most (its page caches, statements), process-wide."""
    try:
        lib = ctypes.CDLL("libsqlite3.so.0")
    except OSError:
        return {}
    lib.sqlite3_memory_used.restype = ctypes.c_int64
    lib.sqlite3_memory_highwater.restype = ctypes.c_int64
    lib.sqlite3_memory_highwater.argtypes = [ctypes.c_int]
    return {"sqlite_used": lib.sqlite3_memory_used(), "sqlite_peak": lib.sqlite3_memory_highwater(0)}


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
        lines += [f"  {k} {v / 1e6:.1f} MB" for k, v in
                  {**heap(), **mappings(), **pymalloc(), **sqlite_memory()}.items()]
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
