"""`python -m tests.soak` (make soak): 20 simulated machines, a real mosquitto, the daemon in its own
process, random faults for SOAK_SECONDS (default 600); fails on any lost sample or any growth.

Faults, one at a time at random intervals: every CNC fault of the simulator on a random machine, a broker
kill for SOAK_OUTAGE_S (default 30) with the daemon kept away until the checker is back, a dead link
(swallowed traffic, no FIN), and a cut of the daemon's MQTT connections. Every few seconds: the daemon's
RSS, descriptors, threads and tasks, the spool depth, collected vs delivered.

Environment: SOAK_SECONDS, SOAK_MACHINES (20), SOAK_OUTAGE_S (30), SOAK_SEED, SOAK_RSS_GROWTH_MB (16).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import random
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from edge.publish import payload as pl
from edge.service.blocking_pool import BLOCKING_WORKERS
from edge.sim.fleet import Fleet, Machine, MachineSpec
from tests.helpers import Mosquitto, mosquitto_binary
from tests.integration.delivery import keep_changing, key_of
from tests.integration.tcp_relay import TcpRelay

Key = tuple[Any, ...]


class Checker:
    """Subscribes to everything and keeps only the dedup keys of what arrives (bounded by the data)."""

    def __init__(self, broker: Mosquitto) -> None:
        self.keys: set[Key] = set()
        self.messages = 0
        self.duplicates = 0
        self.historical = 0
        self._aliases: dict[str, dict[int, str]] = defaultdict(dict)
        self._lock = threading.Lock()
        self.subscribed = threading.Event()
        self.client = paho.Client(CallbackAPIVersion.VERSION2, client_id="soak-checker")
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *a: self.subscribed.set()
        self.client.on_message = self._on_message
        self.client.reconnect_delay_set(0.05, 0.2)  # type: ignore[arg-type]
        self.client.connect_async(broker.host, broker.port, keepalive=5)
        self.client.loop_start()

    def _on_connect(self, client: paho.Client, *args: Any) -> None:
        self.subscribed.clear()
        client.subscribe([("spBv1.0/#", 1), ("focas/#", 1)])

    def _add(self, key: Key, historical: bool) -> None:
        if key in self.keys:
            self.duplicates += 1
        self.keys.add(key)
        self.historical += historical

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        with self._lock:
            self.messages += 1
            parts = msg.topic.split("/")
            if parts[0] == "spBv1.0" and len(parts) == 5:
                kind, device = parts[2], parts[4]
                if kind == "DBIRTH":  # a value a birth carries has reached the host (the replay skips it)
                    for m in pl.decode(bytes(msg.payload)).metrics:
                        self._aliases[device][m.alias] = m.name
                        if not m.is_null:
                            value = m.string_value if m.WhichOneof("value") == "string_value" else None
                            self.keys.add(("spb", *key_of(device, m.name, m.timestamp, value)))
                elif kind == "DDATA":
                    for m in pl.decode(bytes(msg.payload)).metrics:
                        name = self._aliases[device].get(m.alias, f"?{m.alias}")
                        value = m.string_value if m.WhichOneof("value") == "string_value" else None
                        self._add(("spb", *key_of(device, name, m.timestamp, value)), m.is_historical)
            elif parts[0] == "focas" and len(parts) >= 3 and parts[2] in ("state", "history", "events") \
                    and not msg.retain:
                doc = json.loads(msg.payload)
                name = doc.get("name") or "/".join(parts[3:])
                self._add(("json", *key_of(parts[1], name, int(doc["ts"]), doc["value"])),
                          bool(doc.get("historical")))

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def config_text(relay: TcpRelay, state_dir: Path, fleet: Fleet) -> str:
    machines = "".join(
        f"  - {{id: m{i + 1}, host: 127.0.0.1, port: {m.port}, "
        f"poll: {{periods: {{status: 0.25s, macros: 0.25s}}, macros: [500]}}, "
        f"timeouts: {{request_s: 2, connect_s: 2, backoff_initial_s: 0.5, backoff_max_s: 5}}}}\n"
        for i, m in enumerate(fleet))
    return f"""
mqtt:
  host: {relay.host}
  port: {relay.port}
  keepalive: 10
  formats: [sparkplug, json]
  sparkplug: {{group_id: soak, edge_node_id: gw}}
  json: {{prefix: focas}}
state_dir: {state_dir}
machines:
{machines}"""


CNC_FAULTS: list[tuple[str, dict[str, Any], bool]] = [  # name, FaultPlan change, drop sessions now
    ("refuse", {"refuse": -1}, True),
    ("drop", {"drop_after": 1}, False),
    ("hang", {"hang": 1}, False),
    ("garbage", {"garbage": 1}, False),
    ("slow", {"latency": 3.0}, False),
    ("sessions", {"max_sessions": 0}, True),
]


class Soak:
    def __init__(self, seconds: float, machines: int, outage_s: float, seed: int) -> None:
        self.seconds = seconds
        self.machines = machines
        self.outage_s = outage_s
        self.rng = random.Random(seed)
        self.seed = seed
        self.reports: list[dict[str, Any]] = []
        self.faults: list[str] = []
        self.outages: list[dict[str, float]] = []
        self.problems: list[str] = []

    async def run(self) -> int:
        binary = mosquitto_binary()
        if binary is None:
            print("soak: mosquitto is not installed (make broker-check)", file=sys.stderr)
            return 2
        work = Path(tempfile.mkdtemp(prefix="focas-soak-"))
        broker = Mosquitto(binary)
        broker.start()
        relay = TcpRelay(broker.host, broker.port)
        await relay.start()
        fleet = Fleet([MachineSpec(profile="30i") for _ in range(self.machines)], base_port=0)
        await fleet.start()
        changer = asyncio.create_task(keep_changing(list(fleet), period_s=0.25))
        checker = Checker(broker)
        config, keys_file = work / "edge.yaml", work / "collected.jsonl"
        config.write_text(config_text(relay, work / "state", fleet))
        env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])}
        child = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "tests.soak.child", str(config), str(keys_file),
            stdout=asyncio.subprocess.PIPE, stderr=(work / "daemon.log").open("ab"), env=env)
        reader = asyncio.create_task(self._read_reports(child))
        print(f"soak: {self.machines} machines, {self.seconds:.0f} s, outage {self.outage_s:.0f} s, "
              f"seed {self.seed}, work dir {work}", flush=True)
        try:
            await self._faults(broker, relay, fleet, checker)
            for m in fleet:  # the end: no faults, everything must drain
                m.faults.clear()
            relay.accepting = True
            if not await self._until(lambda: self._last("born") and self._last("online") == self.machines
                                     and self._last("spool_rows") == 0, 180):
                self.problems.append(f"not settled within 180 s after the faults; last report {self.reports[-1:]}")
            await asyncio.sleep(12)  # two more reports at rest: the growth baseline's counterpart
            child.send_signal(signal.SIGTERM)
            code = await asyncio.wait_for(child.wait(), 60)
        except BaseException:
            code = -1
            raise
        finally:
            with contextlib.suppress(ProcessLookupError):
                child.kill()
            reader.cancel()
            changer.cancel()
            await fleet.close()
            await relay.close()
            await asyncio.sleep(1.0)  # the checker's last messages
            checker.close()
            broker.close()
        return self._verdict(code, keys_file, checker, work)

    async def _read_reports(self, child: asyncio.subprocess.Process) -> None:
        assert child.stdout is not None
        async for raw in child.stdout:
            with contextlib.suppress(ValueError):
                line = json.loads(raw)
                self.reports.append(line)
                print(f"  t={line['t']:>6}s rss={line['rss'] / 2**20:6.1f}MiB fds={line['fds']:3d} "
                      f"threads={line['threads']:2d}+{line['pool_threads']} tasks={line['tasks']:3d} "
                      f"spool={line['spool_rows']:5d} "
                      f"online={line['online']:2d} suspect={line['suspect_dead']} dropped={line['samples_dropped']}",
                      flush=True)

    def _last(self, key: str) -> Any:
        return self.reports[-1].get(key) if self.reports else None

    async def _until(self, condition: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.5)
        return True

    async def _faults(self, broker: Mosquitto, relay: TcpRelay, fleet: Fleet, checker: Checker) -> None:
        end = time.monotonic() + self.seconds
        outage_at: float | None = time.monotonic() + self.seconds * 0.4  # one broker outage per run, mid-way
        await asyncio.sleep(min(20.0, self.seconds * 0.1))
        while time.monotonic() < end - 20:
            if outage_at is not None and time.monotonic() >= outage_at:
                outage_at = None
                await self._broker_outage(broker, relay, checker)
                continue
            choice = self.rng.random()
            if choice < 0.75:
                await self._cnc_fault(self.rng.choice(list(fleet)))
            elif choice < 0.9:
                self.faults.append("dead link")
                relay.blackhole()
                await asyncio.sleep(self.rng.uniform(3, 8))
                relay.cut()
            else:
                self.faults.append("mqtt cut")
                relay.cut()
            await asyncio.sleep(self.rng.uniform(3, 10))

    async def _cnc_fault(self, machine: Machine) -> None:
        name, change, drop = self.rng.choice(CNC_FAULTS)
        self.faults.append(f"{name}@{machine.name}")
        machine.faults.update(change)
        if drop:
            machine.drop_connections()
        await asyncio.sleep(self.rng.uniform(2, 6))
        machine.faults.clear()

    async def _broker_outage(self, broker: Mosquitto, relay: TcpRelay, checker: Checker) -> None:
        self.faults.append(f"broker outage {self.outage_s:.0f}s")
        relay.accepting = False
        killed = time.monotonic()
        broker.stop(kill=True)
        checker.subscribed.clear()
        await asyncio.sleep(self.outage_s)
        broker.start()
        if not await self._until(checker.subscribed.is_set, 30):
            self.problems.append("the checker did not resubscribe after the broker restart")
        reopened = time.monotonic()
        relay.accepting = True
        connects = relay.accepted
        await self._until(lambda: relay.accepted >= connects + 2, 120)  # both MQTT connections back
        born = time.monotonic()
        if not await self._until(lambda: self._last("spool_rows") == 0 and self._last("born"), 300):
            self.problems.append("the spool did not drain within 300 s of the broker's return")
        self.outages.append({"outage_s": round(reopened - killed, 1), "reconnect_s": round(born - reopened, 1),
                             "replay_done_s": round(time.monotonic() - reopened, 1)})

    def _verdict(self, code: int, keys_file: Path, checker: Checker, work: Path) -> int:
        collected: set[Key] = set()
        for raw in keys_file.read_text().splitlines():
            device, name, ts, value = json.loads(raw)
            collected.add(key_of(device, name, ts, value))
        problems = list(self.problems)
        if code != 0:
            problems.append(f"daemon exit code {code}")
        for fmt in ("spb", "json"):
            got = {k[1:] for k in checker.keys if k[0] == fmt}
            missing = collected - got
            print(f"soak: {fmt}: collected {len(collected)} samples, delivered {len(collected & got)}, "
                  f"missing {len(missing)}", flush=True)
            if missing:
                problems.append(f"{fmt}: {len(missing)} samples lost, e.g. {sorted(missing, key=str)[:3]}")
        # Growth is compared between two reports "at rest" (every machine online, born, spool empty): the
        # first after the warm-up and the last before the stop.
        warm_up = min(60.0, self.seconds * 0.1)
        rest = [r for r in self.reports if r["spool_rows"] == 0 and r["online"] == self.machines and r["born"]
                and r["t"] >= warm_up]
        if len(rest) >= 2:
            start, final = rest[0], rest[-1]
            growth_mb = (final["rss"] - start["rss"]) / 2**20
            limit = float(os.environ.get("SOAK_RSS_GROWTH_MB", "16"))
            print(f"soak: rss {start['rss'] / 2**20:.1f} -> {final['rss'] / 2**20:.1f} MiB, fds {start['fds']} -> "
                  f"{final['fds']}, threads {start['threads']} -> {final['threads']} (blocking pool "
                  f"{start['pool_threads']} -> {final['pool_threads']}), tasks {start['tasks']} -> {final['tasks']}",
                  flush=True)
            if growth_mb > limit:
                problems.append(f"RSS grew {growth_mb:.1f} MiB (limit {limit})")
            for key in ("fds", "threads", "tasks"):
                if final[key] > start[key]:
                    problems.append(f"{key} grew {start[key]} -> {final[key]}")
            # The blocking pool starts workers as its calls overlap and keeps them: growth to its bound is fine.
            most = max(r["pool_threads"] for r in self.reports)
            if most > BLOCKING_WORKERS:
                problems.append(f"blocking pool had {most} threads, above its bound of {BLOCKING_WORKERS}")
        else:
            problems.append("no reports at rest to compare")
        print(f"soak: faults injected ({len(self.faults)}): {', '.join(self.faults)}", flush=True)
        print(f"soak: broker outages: {json.dumps(self.outages)}; checker messages {checker.messages}, "
              f"duplicates {checker.duplicates}, historical {checker.historical}", flush=True)
        if problems:
            print("soak: FAILED\n  - " + "\n  - ".join(problems), flush=True)
            print(f"soak: logs kept in {work}")
            return 1
        shutil.rmtree(work, ignore_errors=True)
        print("soak: PASSED (no loss, no growth)", flush=True)
        return 0


def main() -> int:
    seconds = float(os.environ.get("SOAK_SECONDS", "600"))
    machines = int(os.environ.get("SOAK_MACHINES", "20"))
    outage = float(os.environ.get("SOAK_OUTAGE_S", "30"))
    seed = int(os.environ.get("SOAK_SEED", str(random.randrange(1 << 30))))
    return asyncio.run(Soak(seconds, machines, outage, seed).run())


if __name__ == "__main__":
    sys.exit(main())
