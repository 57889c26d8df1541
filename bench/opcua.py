"""OPC UA server cost: the fleet benchmark's machines (100 x 10 Hz by default) with the server off, on in its
own thread, and on in the daemon's event loop, each time with one client (its own process, Sign&Encrypt,
user + password) subscribed to every metric of every machine.

Per mode: the daemon's CPU (user+sys) per machine-cycle and in cores, achieved cycles, poll overruns,
change-to-broker p99 (MQTT, the same subscriber as the fleet benchmark: does OPC UA disturb it?) and, with
the server on, change-to-client p50/p99 (the simulator stamps a macro with its clock; the client notes
receipt) and sample-to-client (SourceTimestamp -> receipt). Targets from issue 28: extra CPU <= 30 % over
the fleet without the server, change-to-client p99 <= 100 ms.

    python -m bench opcua [--quick] [--sizes 100] [--duration 20] [--repeat 1] [--pin] [--no-burst]
                          [--modes off,loop,burn --burn-cores 0.3]

--pin: the daemon on CPU 0, every other process of the rig (simulators, broker, this process with the MQTT
subscriber, the OPC UA client, the burner) on CPU 1, in every mode (bench.pinning). Mode `burn`: off plus a
process burning `--burn-cores` of a CPU (on CPU 1 with --pin), the load of a client with nothing to serve.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import statistics
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil

from bench import pinning
from bench.fleet import (
    GROUP,
    FleetOptions,
    _cpu,
    _window,
    config_text,
    read_diagnosis,
    start_fleet_sims,
    wait_until,
)
from bench.procs import REPO, DaemonProcess, SimProcess, python_env
from bench.report import Check, Result, percentile
from bench.simproc import STAMP_MODULO
from bench.subscriber import LatencySubscriber
from bench.workload import STAMP_MACRO
from tests.helpers import Mosquitto, free_port, mosquitto_binary

MODES = ("off", "thread", "loop")
# --diagnose: the runner of each mode's daemon (bench.latency_daemon's probes; with the server on, every
# request's holds of the loop too), by default bench.latency_daemon
_DIAGNOSE_MODULES = {"ballast": "bench.opcua_ballast", "thread": "bench.opcua_holds", "loop": "bench.opcua_holds"}
# "idle": the server on the daemon's loop with its address space built but no client; "ballast": the server
# off, the daemon holding an inert heap as large as the server's (bench.opcua_ballast): what the heap alone
# costs (asked for with --modes, not run by default)
# "burn": the server off and a burner process (bench.pinning.Burner) taking --burn-cores of a CPU: the rig's
# extra load without the server's work, the control for contention
ALL_MODES = (*MODES, "idle", "ballast", "burn")
SERVERLESS = ("off", "ballast", "burn")
CLIENTLESS = ("off", "idle", "ballast", "burn")
BURN_CORES = 0.3
NODE_MODULES = REPO / ".node" / "node_modules"
USER, PASSWORD = "bench", "bench-password"
EXTRA_CPU_TARGET_PCT = 30.0
CHANGE_P99_TARGET_MS = 100.0


def opcua_section(mode: str, port: int, password_file: Path) -> str:
    if mode in SERVERLESS:
        return ""
    mode = "loop" if mode == "idle" else mode
    return (f"opcua:\n  enabled: true\n  host: 127.0.0.1\n  port: {port}\n  threaded: {str(mode == 'thread').lower()}\n"
            f"  users:\n    - {{username: {USER}, password_file: {password_file}}}\n")


class ClientProcess:
    """bench/opcua_client.js (node-opcua) as a child process: a client whose own decoding stays light, so the
    gateway is measured, not the client (a Python client needed most of a core at 100 machines)."""

    def __init__(self, url: str, pki_dir: Path, log: Path) -> None:
        node = shutil.which("node")
        if node is None or not (NODE_MODULES / "node-opcua").is_dir():
            raise RuntimeError(f"the OPC UA benchmark's client needs node and node-opcua in {NODE_MODULES} "
                               "(bash scripts/ensure-node-opcua.sh)")
        self._log = open(log, "ab")  # noqa: SIM115 - closed in stop()
        settings = {"url": url, "user": USER, "password": PASSWORD, "namespaceUri": "urn:focas-edge:machines",
                    "stampMetric": f"Macro/{STAMP_MACRO}", "pki": str(pki_dir), "modulo": STAMP_MODULO}
        self.proc = subprocess.Popen([node, str(REPO / "bench" / "opcua_client.js"), json.dumps(settings)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     cwd=REPO, env={**python_env(), "NODE_PATH": str(NODE_MODULES)})

    def answer(self, command: str | None = None) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        if command is not None:
            self.proc.stdin.write(command + "\n")
            self.proc.stdin.flush()
        while True:  # node-opcua prints its own banner lines; ours are the JSON objects
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"OPC UA client exited with {self.proc.wait(10)}")
            if line.startswith("{"):
                answer = dict(json.loads(line))
                if "error" in answer and command != "burst":
                    raise RuntimeError(f"OPC UA client: {answer['error']}")
                return answer

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write("stop\n")
                self.proc.stdin.close()
                self.proc.wait(15)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()


def run_mode(mode: str, machines: int, duration_s: float, warmup_s: float,
             profile_to: Path | None = None, diagnose: bool = False, pin: bool = False,
             burn_cores: float = BURN_CORES, with_burst: bool = True) -> dict[str, Any]:
    """One measurement; every process it starts is stopped before it returns. `profile_to`: the daemon runs
    under pyinstrument and its report is written there (its CPU figures then include the profiler's).
    `diagnose`: under bench.latency_daemon's probes (GC pauses by generation, the loop thread's own CPU).
    `pin`: the daemon on pinning.DAEMON_CPUS, this process and so every other child on pinning.RIG_CPUS
    (restored on the way out)."""
    binary = mosquitto_binary()
    if binary is None:
        raise RuntimeError("mosquitto is not installed (make bench runs scripts/ensure-mosquitto.sh)")
    own_cpus = frozenset(os.sched_getaffinity(0))
    if pin:
        if not own_cpus >= (pinning.DAEMON_CPUS | pinning.RIG_CPUS):
            raise RuntimeError(f"--pin needs CPUs {sorted(pinning.DAEMON_CPUS | pinning.RIG_CPUS)}; "
                               f"this process may use {sorted(own_cpus)}")
        pinning.pin(os.getpid(), pinning.RIG_CPUS)  # every child below inherits it
    workdir = Path(tempfile.mkdtemp(prefix=f"bench-opcua-{mode}-"))
    broker = Mosquitto(binary)
    sims: list[SimProcess] = []
    daemon: DaemonProcess | None = None
    subscriber: LatencySubscriber | None = None
    client: ClientProcess | None = None
    burner: pinning.Burner | None = None
    try:
        broker.start()
        broker_process = psutil.Process(broker.proc.pid) if broker.proc else None
        subscriber = LatencySubscriber(broker.host, broker.port, GROUP, f"Macro/{STAMP_MACRO}")
        sims = start_fleet_sims(machines)
        ports = [port for sim in sims for port in sim.ports]
        password = workdir / "bench.password"
        password.write_text(PASSWORD)
        opcua_port = free_port()
        config = workdir / "edge.yaml"
        config.write_text(config_text(broker, workdir / "state", ports, 0.1)
                          + opcua_section(mode, opcua_port, password))
        diagnosis = workdir / "diagnosis.json" if diagnose else None
        daemon = DaemonProcess(config, workdir / "daemon.log", profile_to=profile_to, diagnose_to=diagnosis,
                               module=_DIAGNOSE_MODULES.get(mode))
        if pin:  # at once (the interpreter is still importing: no thread of its own yet), again before the window
            pinning.pin(daemon.proc.pid, pinning.DAEMON_CPUS)
        sub, proc = subscriber, daemon.proc
        wait_until(lambda: len(sub.births) >= machines or proc.poll() is not None, 30 + machines * 0.2,
                   f"DBIRTH of {machines} machines")
        if proc.poll() is not None:
            raise RuntimeError(f"daemon exited with {proc.returncode}; see {workdir / 'daemon.log'}")
        subscribed: dict[str, Any] = {}
        if mode == "burn":
            burner = pinning.Burner(burn_cores)
        if mode not in CLIENTLESS:
            time.sleep(SUBSCRIBE_SETTLE_S)  # the server's births applied and their overruns reported first
        overruns_before_client = subscriber.overruns or 0
        if mode not in CLIENTLESS:
            started = time.monotonic()
            client = ClientProcess(f"opc.tcp://127.0.0.1:{opcua_port}/focas-edge", workdir / "client-pki",
                                   workdir / "client.log")
            subscribed = client.answer()
            subscribed["subscribe_s"] = time.monotonic() - started
        time.sleep(warmup_s)
        if client is not None:
            client.answer("start")
        # the poll overruns while the client subscribed (one CreateMonitoredItems of every item) and warmed up
        subscribe_overruns = (subscriber.overruns or 0) - overruns_before_client
        pinned: dict[str, Any] = {}
        if pin:
            pinned["daemon_threads_pinned"] = pinning.pin(daemon.proc.pid, pinning.DAEMON_CPUS)
            rig = {"bench": os.getpid(), **{f"sim{i}": sim.proc.pid for i, sim in enumerate(sims)},
                   **({"broker": broker.proc.pid} if broker.proc else {}),
                   **({"client": client.proc.pid} if client else {}), **({"burner": burner.proc.pid} if burner else {})}
            strays = (pinning.check_pinned({"daemon": daemon.proc.pid}, pinning.DAEMON_CPUS)
                      + pinning.check_pinned(rig, pinning.RIG_CPUS))
            if strays:
                raise RuntimeError(f"--pin: not pinned: {', '.join(strays)}")
            pinned["rig_processes_pinned"] = len(rig)
        others = {"client": psutil.Process(client.proc.pid) if client else None,
                  "burner": psutil.Process(burner.proc.pid) if burner else None}
        others_before = {name: _cpu(p) for name, p in others.items()}
        per_cpu_before = psutil.cpu_times(percpu=True)
        measured = _window(FleetOptions(machines, duration_s=duration_s), daemon, sims, subscriber, broker_process,
                           diagnosis)
        per_cpu = pinning.cpu_busy_pct(per_cpu_before, psutil.cpu_times(percpu=True))
        for name, process in others.items():
            measured[f"{name}_cores"] = (_cpu(process) - others_before[name]) / measured["window_s"]
        measured["rig_cores"] = sum(measured[f"{name}_cores"] for name in ("sim", "broker", "subscriber", *others))
        measured.update({f"cpu{i}_busy_pct": busy for i, busy in enumerate(per_cpu)}, pinned=pin, **pinned)
        if client is not None:
            seen = client.answer("report")
            measured["client_items"] = subscribed.get("items", 0)
            measured["subscribe_s"] = subscribed.get("subscribe_s", 0.0)
            measured["subscribe_overruns"] = subscribe_overruns
            measured["client_notifications_per_s"] = seen["notifications"] / max(seen["seconds"], 1e-9)
            measured["client_change_p50_ms"] = percentile([v / 1000 for v in seen["change_ms"]], 50) * 1000
            measured["client_change_p99_ms"] = percentile([v / 1000 for v in seen["change_ms"]], 99) * 1000
            measured["client_changes_seen"] = len(seen["change_ms"])
            if seen.get("wait_ms"):  # the change's wait for the poll that read it (part of change-to-client)
                measured["client_wait_p50_ms"] = percentile([v / 1000 for v in seen["wait_ms"]], 50) * 1000
                measured["client_wait_p99_ms"] = percentile([v / 1000 for v in seen["wait_ms"]], 99) * 1000
            measured["client_sample_p50_ms"] = percentile([v / 1000 for v in seen["sample_ms"]], 50) * 1000
            measured["client_sample_p99_ms"] = percentile([v / 1000 for v in seen["sample_ms"]], 99) * 1000
            if diagnosis is not None and with_burst:
                daemon.proc.send_signal(signal.SIGUSR1)  # the probes' window: the burst alone
            if with_burst:
                measured.update(burst(client, subscriber))
            if diagnosis is not None and with_burst:  # the loop's lag over the burst; the requests' holds
                after = read_diagnosis(daemon, diagnosis)
                measured["burst_loop_lag"] = after["loop_lag"]
                measured["holds"] = after.get("holds", {})
        measured["mode"] = mode
        return measured
    finally:
        if burner is not None:
            burner.stop()
        if client is not None:
            client.stop()
        if daemon is not None:
            daemon.stop(timeout=20)
        for sim in sims:
            sim.stop()
        if subscriber is not None:
            subscriber.close()
        broker.close()
        shutil.rmtree(workdir, ignore_errors=True)
        if pin:
            pinning.pin(os.getpid(), own_cpus)


def burst(client: ClientProcess, subscriber: LatencySubscriber) -> dict[str, Any]:
    """The client creates 10,000 monitored items in one request while the MQTT subscriber times the data:
    what the poll loop and MQTT feel while the server works through the largest single step."""
    subscriber.take()
    overruns = subscriber.overruns or 0
    subscriber.recording = True
    took = client.answer("burst").get("burst_s", float("nan"))  # nan: the burst failed (client.log)
    time.sleep(BURST_SETTLE_S)  # the latencies right after, and one node-metrics period for the overruns
    subscriber.recording = False
    change, _ = subscriber.take()
    return {"burst_s": took, "burst_mqtt_change_p99_ms": percentile(change, 99) * 1000,
            "burst_mqtt_change_max_ms": max(change, default=float("nan")) * 1000,
            "burst_overruns": (subscriber.overruns or 0) - overruns}


BURST_SETTLE_S = 6.0
# before the client subscribes: the OPC UA births (applied after MQTT's) done and one node-metrics period
# passed, so `subscribe_overruns` counts the subscription's, not the births'
SUBSCRIBE_SETTLE_S = 8.0


def diagnosis_summary(run_: dict[str, Any], machines: int) -> str:
    """The probes' figures per machine-cycle: the loop thread's CPU (the rest is other threads'), GC pauses."""
    d, cycles = run_["diagnosis"], run_["cycles_per_s"] * run_["window_s"]
    gcs = ", ".join(f"{g} {d['gc'][g].get('n', 0)}x {d['gc'][g].get('sum_ms', 0.0) / cycles * 1000:.1f} us"
                    for g in ("gen0", "gen1", "gen2"))
    return (f"loop thread {d['loop_thread_ran_s'] / cycles * 1e6:.0f} us/cycle; GC {gcs}; tracked "
            f"{d['gc_tracked_objects']:,}, frozen {d['gc_frozen_objects']:,}")

KEYS = ("cpu_us_per_cycle", "sys_us_per_cycle", "wakeups_per_cycle", "gateway_cores", "rss_mb", "achieved_pct",
        "overruns", "change_p99_ms", "client_items", "subscribe_s", "subscribe_overruns", "client_notifications_per_s",
        "client_change_p50_ms", "client_change_p99_ms", "client_wait_p50_ms", "client_wait_p99_ms",
        "client_sample_p50_ms", "client_sample_p99_ms", "burst_s",
        "burst_mqtt_change_p99_ms", "burst_mqtt_change_max_ms", "burst_overruns", "steal_pct",
        "client_cores", "burner_cores", "sim_cores", "broker_cores", "subscriber_cores", "rig_cores",
        "host_cpu_pct", "cpu0_busy_pct", "cpu1_busy_pct")
# per run, beside the medians (`<key>_runs`): the pairs behind a median
RUN_KEYS = ("cpu_us_per_cycle", "achieved_pct", "overruns", "client_change_p99_ms", "client_sample_p99_ms",
            "client_cores", "rig_cores", "cpu0_busy_pct", "cpu1_busy_pct")


def command_line(quick: bool, machines: int, duration: float, repeats: int, modes: tuple[str, ...],
                 diagnose: bool, pin: bool = False, burn_cores: float = BURN_CORES, with_burst: bool = True) -> str:
    """The command that repeats a run (options at their default left out)."""
    return (f"python -m bench opcua{' --quick' if quick else ''} --sizes {machines} --duration {duration:g} "
            f"--repeat {repeats}{'' if modes == MODES else ' --modes ' + ','.join(modes)}"
            f"{' --diagnose' if diagnose else ''}{' --pin' if pin else ''}"
            f"{f' --burn-cores {burn_cores:g}' if 'burn' in modes and burn_cores != BURN_CORES else ''}"
            f"{'' if with_burst else ' --no-burst'}")


def run(quick: bool = False, machines: int | None = None, duration_s: float | None = None,
        repeats: int = 1, modes: tuple[str, ...] = MODES, diagnose: bool = False, pin: bool = False,
        burn_cores: float = BURN_CORES, with_burst: bool = True) -> Result:
    unknown = sorted(set(modes) - set(ALL_MODES))
    if unknown or "off" not in modes:
        raise ValueError(f"opcua modes must include off and be among {', '.join(ALL_MODES)}; got {', '.join(modes)}")
    machines = machines or (20 if quick else 100)
    duration = duration_s or (5.0 if quick else 20.0)
    result = Result("opcua", command_line(quick, machines, duration, repeats, modes, diagnose, pin, burn_cores,
                                          with_burst))
    rows: dict[str, dict[str, Any]] = {}
    for _ in range(repeats):
        for mode in modes:  # interleaved, so a slow phase of the host hits every mode alike
            run_ = run_mode(mode, machines, duration, 1.0 if quick else 3.0, diagnose=diagnose, pin=pin,
                            burn_cores=burn_cores, with_burst=with_burst)
            print(f"  opcua {mode:<6} N={machines}: {run_['cpu_us_per_cycle']:.0f} us/cycle "
                  f"({run_['gateway_cores']:.2f} cores, sys {run_['sys_us_per_cycle']:.0f} us, "
                  f"{run_['wakeups_per_cycle']:.2f} switches/cycle), client change p99 "
                  f"{run_.get('client_change_p99_ms', float('nan')):.0f} ms (wait for the poll p99 "
                  f"{run_.get('client_wait_p99_ms', float('nan')):.0f} ms, SourceTimestamp-to-client p99 "
                  f"{run_.get('client_sample_p99_ms', float('nan')):.0f} ms)", flush=True)
            print(f"  opcua {mode:<6} {'pinned' if pin else 'unpinned'}: polls {run_['achieved_pct']:.1f} %, "
                  f"{run_['overruns']} overruns; rig {run_['rig_cores']:.2f} cores (client "
                  f"{run_['client_cores']:.2f}, burner {run_['burner_cores']:.2f}, sims {run_['sim_cores']:.2f}, "
                  f"broker {run_['broker_cores']:.2f}, subscriber {run_['subscriber_cores']:.2f}); CPU busy "
                  + ", ".join(f"{i} {run_[f'cpu{i}_busy_pct']:.0f} %" for i in range(2) if f'cpu{i}_busy_pct' in run_),
                  flush=True)
            if "diagnosis" in run_:
                print(f"  opcua {mode:<6} {diagnosis_summary(run_, machines)}", flush=True)
            if "holds" in run_:
                lag = run_["burst_loop_lag"]
                print(f"  opcua {mode:<6} burst loop lag p99 {lag.get('p99_ms', 0):.0f} ms max "
                      f"{lag.get('max_ms', 0):.0f} ms; longest holds: " + "; ".join(
                          f"{key} {hold['top5_cpu_ms']} ms CPU ({hold['steps']} steps)"
                          for key, hold in list(run_["holds"].items())[:6]), flush=True)
            rows.setdefault(mode, {"mode": mode, "machines": machines, "runs": []})["runs"].append(run_)
    for row in rows.values():
        runs = row.pop("runs")
        if "diagnosis" in runs[0]:
            row["diagnosis"] = runs[0]["diagnosis"]
        for key in KEYS:
            values = [r[key] for r in runs if key in r]
            row[key] = statistics.median(values) if values else None
        for key in RUN_KEYS:
            row[f"{key}_runs"] = [r.get(key) for r in runs]
        row["pinned"] = pin
        result.rows.append(row)
    base = rows["off"]["cpu_us_per_cycle"]
    for mode in (m for m in ("thread", "loop", "idle", "ballast", "burn") if m in rows):
        extra = 100 * (rows[mode]["cpu_us_per_cycle"] / base - 1)
        rows[mode]["extra_cpu_pct"] = extra
        rows[mode]["extra_cpu_pct_pairs"] = pinning.paired_extra_pct(rows["off"]["cpu_us_per_cycle_runs"],
                                                                     rows[mode]["cpu_us_per_cycle_runs"])
        result.checks.append(Check(f"extra gateway CPU, server in its {mode}", extra, EXTRA_CPU_TARGET_PCT, "<=",
                                   " %"))
        if mode in CLIENTLESS:
            continue
        result.checks.append(Check(f"change-to-client p99, server in its {mode}", rows[mode]["client_change_p99_ms"],
                                   CHANGE_P99_TARGET_MS, "<=", " ms"))
    result.notes.append("one client (node-opcua, own process, Basic256Sha256 Sign&Encrypt, user+password) "
                        "subscribed to every variable below every machine's Metrics folder, publishing interval 20 ms")
    result.notes.append("burst = the client creates 10,000 more monitored items in one request; burst_mqtt_* = "
                        "change-to-broker latency over that request and the 6 s after it")
    result.notes.append("change = simulator stamps a macro with its clock -> client receipt (includes up to one "
                        "poll period); wait = that change -> the read that saw it (SourceTimestamp), the poll "
                        "period's part of change; sample = SourceTimestamp (CNC time of the read) -> client receipt")
    result.notes.append("CPU = user+sys of the daemon process only (the client and simulators are not counted)")
    if pin:
        result.notes.append(f"--pin: the daemon on CPU {sorted(pinning.DAEMON_CPUS)}, every other process of the "
                            f"rig on CPU {sorted(pinning.RIG_CPUS)} (every thread checked before the window)")
    if "burn" in modes:
        result.notes.append(f"burn = off plus a burner process taking {burn_cores:g} of a CPU (bench.pinning)")
    return result
