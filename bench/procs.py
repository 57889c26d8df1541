"""Child processes a benchmark owns: the simulator fleets, the daemon and the broker; always stopped."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import psutil

from tests.helpers import Mosquitto, mosquitto_binary

REPO = Path(__file__).resolve().parent.parent


def python_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


class SimProcess:
    """`python -m bench.simproc` as a child: ports once ready, stats on request."""

    def __init__(self, machines: int, *, latency: float = 0.0, stamp_macro: int = 0, clock_macro: int = 0,
                 fill_macros: str = "", packed: bool = False, spread_clocks_from: int | None = None,
                 timeout: float = 60.0) -> None:
        command = [sys.executable, "-m", "bench.simproc", "--machines", str(machines), "--latency", str(latency)]
        if stamp_macro:
            command += ["--stamp-macro", str(stamp_macro)]
        if clock_macro:
            command += ["--clock-macro", str(clock_macro)]
        if fill_macros:
            command += ["--fill-macros", fill_macros]
        if packed:
            command.append("--packed")
        if spread_clocks_from is not None:
            command += ["--spread-clocks", str(spread_clocks_from)]
        self.proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     cwd=REPO, env=python_env())
        first = self._line(timeout)
        self.ports: list[int] = first["ports"]
        self.packed_ports: list[int | None] = first.get("packed_ports", [])
        self.process = psutil.Process(self.proc.pid)

    def _line(self, timeout: float) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"simulator process exited with {self.proc.wait(timeout)} before answering")
        return dict(json.loads(line))

    def stats(self) -> dict[str, float]:
        assert self.proc.stdin is not None
        self.proc.stdin.write("stats\n")
        self.proc.stdin.flush()
        return {k: float(v) for k, v in self._line(10).items()}

    def stop(self) -> None:
        if self.proc.poll() is not None:
            return
        try:
            assert self.proc.stdin is not None
            self.proc.stdin.write("stop\n")
            self.proc.stdin.close()
            self.proc.wait(10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(10)


class DaemonProcess:
    """`python -m edge run --config FILE` as a child (optionally under pyinstrument, tracemalloc or the latency
    probes of bench.latency_daemon); its CPU is measurable."""

    def __init__(self, config: Path, log: Path, profile_to: Path | None = None,
                 tracemalloc_to: Path | None = None, diagnose_to: Path | None = None,
                 module: str | None = None, spread_clocks: bool = False) -> None:
        """`module`: with `diagnose_to`, another runner taking the same arguments as bench.latency_daemon;
        `spread_clocks`: tell bench.latency_daemon each CNC clock has its own offset (bench.clocks)."""
        if profile_to is not None:
            command = [sys.executable, "-m", "bench.profiled_daemon", str(config), str(profile_to)]
        elif tracemalloc_to is not None:
            command = [sys.executable, "-m", "bench.memory_daemon", str(config), str(tracemalloc_to)]
        elif diagnose_to is not None:
            command = [sys.executable, "-m", module or "bench.latency_daemon", str(config), str(diagnose_to)]
            command += ["--spread-clocks"] if spread_clocks else []
        else:
            command = [sys.executable, "-m", "edge", "run", "--config", str(config)]
        self._log = open(log, "ab")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(command, stdout=self._log, stderr=subprocess.STDOUT, cwd=REPO,
                                     env=python_env())
        self.process = psutil.Process(self.proc.pid)

    def cpu_seconds(self) -> float:
        times = self.process.cpu_times()
        return float(times.user + times.system)

    def system_seconds(self) -> float:
        """The kernel's share (socket syscalls, epoll): what no Python change can take away."""
        return float(self.process.cpu_times().system)

    def context_switches(self) -> int:
        """Voluntary switches: each one is the process going to sleep and being woken again."""
        return int(self.process.num_ctx_switches().voluntary)

    def loop_schedstat(self) -> tuple[float, float]:
        """(ran, waited for a CPU) seconds of the daemon's main thread (its event loop) since it started."""
        try:
            ran, waited, _ = Path(f"/proc/{self.proc.pid}/task/{self.proc.pid}/schedstat").read_text().split()
        except (OSError, ValueError):
            return float("nan"), float("nan")
        return int(ran) / 1e9, int(waited) / 1e9

    def rss_bytes(self) -> int:
        return int(self.process.memory_info().rss)

    def open_fds(self) -> int:
        return int(self.process.num_fds())

    def stop(self, timeout: float = 30.0) -> int | None:
        try:
            if self.proc.poll() is None:
                self.proc.send_signal(signal.SIGTERM)
                try:
                    self.proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(10)
            return self.proc.returncode
        finally:
            self._log.close()


def stop_sims(sims: list[SimProcess]) -> None:
    for sim in sims:
        sim.stop()


@contextlib.contextmanager
def running_broker() -> Iterator[Mosquitto]:
    """A mosquitto of the benchmark's own on a free port, closed on the way out."""
    binary = mosquitto_binary()
    if binary is None:
        raise RuntimeError("mosquitto is not installed (make bench runs scripts/ensure-mosquitto.sh)")
    broker = Mosquitto(binary)
    try:
        broker.start()
        yield broker
    finally:
        broker.close()
