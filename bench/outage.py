"""A broker outage at scale (issue 25 point 5): N simulated CNCs -> the daemon -> mosquitto, killed and back.

    python -m bench outage --sizes 1000 --period 1 --outage 60 [--duration 20] [--outages 2]

The daemon runs as the soak's child (tests/soak/child.py): every sample the pollers hand the publisher is
appended to a file, and its RSS, descriptors and spool depth are reported every REPORT_S. The soak's checker
subscribes to everything and keeps each delivered value's dedup key. The broker is killed (SIGKILL) for
`--outage` seconds and started again on the same port. Measured: samples lost (collected, never delivered),
the seconds from the broker's return to the daemon's reconnection and to an empty spool, the replay rate
(historical values delivered per second while it drained) against the live rate before the outage, the
live rate while the backlog drained, and RSS and descriptors before, during and after. With `--outages N`
the same daemon lives through N outages, one row each: memory an outage's allocator keeps is reused by the
next (its RSS step comes once), memory it loses grows with each.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from array import array
from collections import Counter, defaultdict
from pathlib import Path
from typing import IO, Any

from bench.fleet import config_text, start_fleet_sims, wait_until
from bench.procs import REPO, python_env, running_broker, stop_sims
from bench.report import Check, Result, percentile
from tests.helpers import Mosquitto
from tests.integration.delivery import key_of
from tests.integration.tcp_relay import TcpRelay
from tests.soak.__main__ import Checker, Key

REPORT_S = 0.5
WARMUP_S = 15.0
CLEAR_TARGET_S = 6.0  # the 60 s backlog cleared within 6 s of the broker's return
REPLAY_RATIO_TARGET = 10.0


class ArrivalCounter(Checker):
    """The soak's checker, also counting live and historical values delivered per second."""

    def __init__(self, broker: Mosquitto) -> None:
        self.live: Counter[int] = Counter()
        self.backlog: Counter[int] = Counter()
        self.lags: dict[int, array[float]] = defaultdict(lambda: array("f"))  # live values' lags (s), by second
        super().__init__(broker)

    def _add(self, key: Key, historical: bool) -> None:
        super()._add(key, historical)
        now = time.time()
        (self.backlog if historical else self.live)[int(now)] += 1
        if not historical:  # key = ("spb", device, name, CNC timestamp in ms, ...)
            self.lags[int(now)].append(now - key[3] / 1000)

    def lag_p99_ms(self, start: float, end: float) -> float:
        """The live values' p99 lag (CNC time of the tick to receipt) over whole seconds in [start, end)."""
        lags = [lag for s in range(int(start) + 1, int(end)) for lag in self.lags.get(s, ())]
        return percentile(lags, 99) * 1000 if lags else float("nan")

    def rate(self, counts: Counter[int], start: float, end: float) -> float:
        """Values per second over whole seconds in [start, end)."""
        seconds = range(int(start) + 1, int(end))
        return sum(counts[s] for s in seconds) / len(seconds) if seconds else float("nan")


class RelayThread:
    """The daemon reaches the broker only through a TCP relay (run on its own event loop thread), so the
    bench decides when the daemon can reach the broker again: after the checker has resubscribed, else the
    first replayed rows (and the births naming their aliases) could reach the broker before the checker."""

    def __init__(self, broker: Mosquitto) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        self.relay = TcpRelay(broker.host, broker.port)
        self.host, self.port = self.relay.host, self.relay.port
        self.open()

    def _call(self, coro: Any) -> None:
        asyncio.run_coroutine_threadsafe(coro, self._loop).result(30)

    def open(self) -> None:
        self._call(self.relay.start())

    def shut(self) -> None:
        """Nothing listens at the relay's port (a connect is refused, as at a broker that is down)."""
        self._call(self.relay.stop_listening())

    def close(self) -> None:
        self._call(self.relay.close())
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()


class SoakChild:
    """`python -m tests.soak.child` with its reports read by a thread; the last report is `last`."""

    def __init__(self, config: Path, keys: Path, log: Path) -> None:
        env = {**python_env(), "SOAK_REPORT_S": str(REPORT_S)}
        self._log: IO[bytes] = log.open("ab")
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.soak.child", str(config), str(keys)],
                                     stdout=subprocess.PIPE, stderr=self._log, cwd=REPO, env=env, text=True)
        self.reports: list[dict[str, Any]] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                report = json.loads(line)
            except ValueError:
                continue
            report["time"] = time.time()
            self.reports.append(report)

    @property
    def last(self) -> dict[str, Any]:
        return self.reports[-1] if self.reports else {}

    def stop(self) -> int:
        try:
            if self.proc.poll() is None:
                self.proc.send_signal(signal.SIGTERM)
                try:
                    self.proc.wait(60)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(10)
            self._reader.join(5)
            return self.proc.returncode
        finally:
            self._log.close()


def run_outage(machines: int, period_s: float, outage_s: float, after_s: float,
               outages: int = 1) -> list[dict[str, Any]]:
    """`outages` outages of one daemon, a row each (the losses counted over all of them, in the last); every
    process it starts is stopped before it returns (the work dir kept if samples were lost)."""
    with contextlib.ExitStack() as stack:
        workdir = Path(tempfile.mkdtemp(prefix="bench-outage-"))
        outcome: dict[str, Any] = {"lost": -1}
        stack.callback(_tidy, workdir, outcome)
        broker = stack.enter_context(running_broker())
        checker = ArrivalCounter(broker)
        stack.callback(checker.close)
        relay = RelayThread(broker)
        stack.callback(relay.close)
        sims = start_fleet_sims(machines, period_s)
        stack.callback(stop_sims, sims)
        ports = [port for sim in sims for port in sim.ports]
        config, keys = workdir / "edge.yaml", workdir / "collected.jsonl"
        config.write_text(config_text(relay, workdir / "state", ports, period_s))
        child = SoakChild(config, keys, workdir / "daemon.log")
        stack.callback(child.stop)
        wait_until(lambda: child.last.get("born") and child.last.get("online") == machines, 60 + machines * 0.1,
                   f"{machines} machines online and born")
        time.sleep(WARMUP_S)
        rows = [_outage(broker, relay, checker, child, machines, period_s, outage_s, after_s)
                for _ in range(outages)]
        outcome["daemon_exit"] = child.stop()
        time.sleep(2.0)  # the checker's last messages
        outcome.update(_losses(keys, checker))
        rows[-1].update(outcome)
        return rows


def _tidy(workdir: Path, outcome: dict[str, Any]) -> None:
    if outcome.get("lost") == 0 and outcome.get("daemon_exit") == 0 and not os.environ.get("BENCH_KEEP_WORKDIR"):
        shutil.rmtree(workdir, ignore_errors=True)
    else:
        print(f"  outage: logs kept in {workdir}", flush=True)


def _outage(broker: Mosquitto, relay: RelayThread, checker: ArrivalCounter, child: SoakChild, machines: int,
            period_s: float, outage_s: float, after_s: float) -> dict[str, Any]:
    _probe(child)  # SOAK_MEMORY_DIR: tracing starts here (tests/soak/memory_probe.py)
    before = dict(child.last)
    live_before = checker.rate(checker.live, time.time() - 10, time.time())
    lag_before = checker.lag_p99_ms(time.time() - 10, time.time())
    killed = time.time()
    broker.stop(kill=True)
    relay.shut()
    checker.subscribed.clear()
    time.sleep(outage_s)
    during = [r for r in child.reports if r["time"] >= killed]
    broker.start()
    wait_until(lambda: checker.subscribed.is_set(), 30, "the checker resubscribed")
    relay.open()  # only now can the daemon reach the broker: the checker misses nothing it sends
    back = time.time()
    _probe(child)
    wait_until(lambda: child.last.get("born") and child.last["time"] > back, 60, "the daemon reborn")
    born = next(r["time"] for r in child.reports if r["time"] > back and r.get("born"))
    wait_until(lambda: child.last["time"] > born and child.last.get("spool_rows") == 0, 900, "the spool drained")
    cleared = child.last["time"]
    _probe(child)
    time.sleep(after_s)
    after = dict(child.last)
    _probe(child)
    backlog = sum(n for s, n in checker.backlog.items() if s >= int(back))
    replay_s = max(cleared - born, REPORT_S)
    replay_rate = backlog / replay_s
    return {
        "machines": machines, "period_s": period_s, "outage_s": round(back - killed, 1),
        "spooled_rows": max((r.get("spool_rows", 0) for r in during), default=0),
        "reconnect_s": born - back, "cleared_after_return_s": cleared - back, "replay_s": cleared - born,
        "backlog_values": backlog, "live_values_per_s": live_before,
        "replay_values_per_s": replay_rate, "replay_x_live": replay_rate / live_before if live_before else float("nan"),
        "live_during_replay_per_s": checker.rate(checker.live, born, cleared) if cleared - born >= 2 else float("nan"),
        "live_p99_ms_before": lag_before,
        "live_p99_ms_during_replay": checker.lag_p99_ms(born - 1, cleared + 1),
        "rss_mb_before": before.get("rss", 0) / 1e6,
        "rss_mb_max_during": max((r["rss"] for r in during), default=0) / 1e6,
        "rss_mb_after": after.get("rss", 0) / 1e6,
        "fds_before": before.get("fds"), "fds_max_during": max((r["fds"] for r in during), default=0),
        "fds_after": after.get("fds"),
        "samples_dropped": after.get("samples_dropped", 0),
    }


def _probe(child: SoakChild) -> None:
    """With SOAK_MEMORY_DIR set, the child writes a memory probe (tests/soak/memory_probe.py)."""
    if os.environ.get("SOAK_MEMORY_DIR"):
        child.proc.send_signal(signal.SIGUSR1)


def _losses(keys: Path, checker: ArrivalCounter) -> dict[str, Any]:
    collected: set[Key] = set()
    for raw in keys.read_text().splitlines():
        device, name, ts, value = json.loads(raw)
        collected.add(key_of(device, name, ts, value))
    delivered = {k[1:] for k in checker.keys if k[0] == "spb"}
    return {"collected": len(collected), "lost": len(collected - delivered), "duplicates": checker.duplicates}


def run(machines: int | None = None, period_s: float | None = None, outage_s: float | None = None,
        duration_s: float | None = None, quick: bool = False, outages: int = 1) -> Result:
    n = machines or (20 if quick else 1000)
    period = period_s or 1.0
    outage = outage_s or (10.0 if quick else 60.0)
    after = duration_s or 10.0
    result = Result("outage", f"python -m bench outage --sizes {n} --period {period:g} --outage {outage:g} "
                              f"--duration {after:g}" + (f" --outages {outages}" if outages > 1 else ""))
    rows = run_outage(n, period, outage, after, outages)
    result.rows += rows
    row = rows[-1]
    print(f"  outage N={n}: lost {row['lost']} of {row['collected']}, reconnect {row['reconnect_s']:.1f} s, "
          f"replay {row['replay_s']:.1f} s at {row['replay_x_live']:.1f}x live, cleared "
          f"{row['cleared_after_return_s']:.1f} s after the return, live p99 {row['live_p99_ms_before']:.0f} ms "
          f"before, {row['live_p99_ms_during_replay']:.0f} ms during the replay", flush=True)
    result.checks += [
        Check(f"samples lost across a {outage:g} s outage, {n} machines", row["lost"], 0, "<="),
        Check("backlog cleared after the broker's return", row["cleared_after_return_s"], CLEAR_TARGET_S, "<=", " s"),
        Check("replay rate against the live rate", row["replay_x_live"], REPLAY_RATIO_TARGET, ">=", "x"),
        Check("RSS after against before the outage", row["rss_mb_after"] - rows[0]["rss_mb_before"], 8.0, "<=", " MB"),
        Check("descriptors after against before the outage", row["fds_after"] - rows[0]["fds_before"], 0, "<="),
    ]
    result.notes.append("values = Sparkplug metrics delivered (dedup keys); live rate over the 10 s before the "
                        "outage; replay = the daemon reborn to its spool empty (reports every "
                        f"{REPORT_S:g} s), reconnect = broker back to the daemon reborn (while the broker is "
                        "down the daemon retries within reconnect_probe_s, 0.5 s, jittered)")
    return result

