"""`python -m bench opcua --pin`: the daemon alone on one CPU, the rest of the rig on the other.

On the 2-core bench host the daemon shares its cores with the simulators, the broker, the MQTT subscriber
and, with the server on, the OPC UA client (node-opcua, its own process): a deployment has that client on
another machine. Pinning (the daemon to DAEMON_CPUS, everything else to RIG_CPUS, in every mode alike)
keeps the rig's work off the daemon's core, so what is left of "extra CPU" is the daemon's own. Affinity is
per thread on Linux: `pin` sets it for every thread a process has, and threads started later inherit their
creator's. `cpu_busy_pct` says whether the rig's CPU kept up (a saturated rig CPU slows the polls instead).

`Burner` is the control: a process that takes about `cores` of a CPU in 20 ms slices, sweeping a buffer larger
than the caches, the load of a client without a server to serve it.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from bench.procs import REPO, python_env

DAEMON_CPUS = frozenset({0})
RIG_CPUS = frozenset({1})
BURN_SLICE_S = 0.02
BURN_BUFFER_BYTES = 8 << 20


def tasks(pid: int) -> list[int]:
    """The thread ids of process `pid` (empty once it is gone)."""
    try:
        return sorted(int(tid) for tid in os.listdir(f"/proc/{pid}/task"))
    except OSError:
        return []


def pin(pid: int, cpus: frozenset[int]) -> int:
    """Every thread of `pid` to `cpus`; the threads set (a thread that ended meanwhile is skipped)."""
    done = 0
    for tid in tasks(pid):
        try:
            os.sched_setaffinity(tid, cpus)
        except (ProcessLookupError, FileNotFoundError):
            continue
        done += 1
    return done


def affinities(pid: int) -> set[frozenset[int]]:
    """The distinct CPU sets of the threads of `pid`: one set when the process is pinned as a whole."""
    found: set[frozenset[int]] = set()
    for tid in tasks(pid):
        try:
            found.add(frozenset(os.sched_getaffinity(tid)))
        except (ProcessLookupError, FileNotFoundError):
            continue
    return found


def check_pinned(pids: dict[str, int], cpus: frozenset[int]) -> list[str]:
    """The names whose process has a thread allowed outside `cpus` (a process gone is not a failure)."""
    return sorted(name for name, pid in pids.items() if any(found != cpus for found in affinities(pid)))


def cpu_busy_pct(before: Sequence[Any], after: Sequence[Any]) -> list[float]:
    """Per CPU, the share of the interval it ran anything (psutil.cpu_times(percpu=True) before and after):
    everything but idle, iowait and the hypervisor's steal."""
    busy: list[float] = []
    for b, a in zip(before, after, strict=True):
        total = sum(a) - sum(b)
        spare = sum(getattr(a, f, 0.0) - getattr(b, f, 0.0) for f in ("idle", "iowait", "steal"))
        busy.append(100 * (total - spare) / total if total > 0 else 0.0)
    return busy


def paired_extra_pct(base: Sequence[float], other: Sequence[float]) -> list[float]:
    """Per interleaved pair (run i of off, run i of the other mode), the other's extra CPU over off, %."""
    return [100 * (o / b - 1) for b, o in zip(base, other, strict=False) if b > 0]


def duty_slices(cores: float, slice_s: float = BURN_SLICE_S) -> tuple[float, float]:
    """(busy, asleep) seconds of each slice for a load of `cores` of one CPU (clamped to 0..1)."""
    share = min(max(cores, 0.0), 1.0)
    return share * slice_s, (1 - share) * slice_s


class Burner:
    """`python -m bench.pinning --cores X` as a child (it inherits this process's affinity)."""

    def __init__(self, cores: float) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "bench.pinning", "--cores", str(cores)],
                                     stdin=subprocess.DEVNULL, cwd=REPO, env=python_env())

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)


def burn(cores: float, seconds: float | None = None) -> None:
    busy, asleep = duty_slices(cores)
    buffer = bytearray(BURN_BUFFER_BYTES)
    view, offset, step = memoryview(buffer), 0, 4096
    ends = None if seconds is None else time.monotonic() + seconds
    while ends is None or time.monotonic() < ends:
        until = time.perf_counter() + busy
        while time.perf_counter() < until:  # touch a page at a time: the caches see a working set, not a spin
            view[offset] = (view[offset] + 1) & 0xFF
            offset = (offset + step + 64) % BURN_BUFFER_BYTES
        if asleep > 0:
            time.sleep(asleep)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m bench.pinning", description="a CPU burner (the control)")
    parser.add_argument("--cores", type=float, required=True, help="share of one CPU to take, 0..1")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this long (default: when killed)")
    options = parser.parse_args()
    with contextlib.suppress(KeyboardInterrupt):
        burn(options.cores, options.seconds)
