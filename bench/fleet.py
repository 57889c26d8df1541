"""Fleet scale: N simulated CNCs (separate processes) -> the daemon (its own process) -> mosquitto.

Per N: the daemon's CPU seconds (user+sys) per machine-cycle, its RSS, achieved cycles/s against the
plan (N machines / the poll period, 100 ms unless --period), poll overruns, change-to-broker latency
measured by a subscriber, and the CNC timestamp error (stamp minus the simulator's clock when it answered,
from a macro that reads as that clock). A cycle is one data PDU the simulators answered (the collector sends
one per tick); the clock-only reads between ticks are counted apart (per machine per minute). Each simulated
CNC clock runs its own offset off this host's (bench.clocks: as hand-set clocks do), unless --same-clock
(every CNC clock this host's: an NTP-synced plant, the rig before 2026-11-26).
"""

from __future__ import annotations

import json
import math
import shutil
import signal
import statistics
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import psutil

from bench.clocks import device_clock_offset
from bench.procs import DaemonProcess, SimProcess
from bench.report import Check, Result, percentile
from bench.subscriber import LatencySubscriber
from bench.workload import CLOCK_MACRO, STAMP_MACRO, machines_section
from tests.helpers import Mosquitto, mosquitto_binary

GROUP = "bench"
MACHINES_PER_SIM = 50  # at least this many to a simulator process
SIM_REQUESTS_PER_S = 250  # and as many more as keep a process at about this many requests a second
MAX_MACHINES_PER_SIM = 200
CPU_TARGET_US = 150.0
RSS_TARGET_MB = 80.0
LATENCY_SLACK_S = 0.020
LARGE_FLEET = 1000  # issue 25's targets hold from here on
LARGE_RSS_TARGET_MB = 120.0
LARGE_SAMPLE_P99_MS = 50.0
LARGE_BIRTHS_S = 30.0
STAMP_TARGET_MS = 20.0  # issue 24: CNC timestamps within 20 ms of the CNC clock (p99)


@dataclass
class FleetOptions:
    machines: int
    period_s: float = 0.1
    duration_s: float = 20.0
    warmup_s: float = 10.0  # after the last birth: the clocks are synchronised a few seconds after it
    profile_to: Path | None = None  # pyinstrument over the whole run (main thread only)
    spy_to: Path | None = None  # py-spy collapsed stacks of the measuring window (all threads)
    py_spy: str = "py-spy"
    tracemalloc_to: Path | None = None  # live Python allocations by module at the window's end (JSON)
    diagnose: bool = False  # the daemon under bench.latency_daemon: loop lag, GC pauses, grid slots in the row
    same_plan: bool = False  # loads and counters every 10th and 100th tick at any period (as at 10 Hz)
    same_clock: bool = False  # every CNC clock this host's (not each its own offset: bench.clocks)


class Endpoint(Protocol):
    """Where the daemon connects: the broker, or a relay in front of it."""

    host: str
    port: int


def config_text(broker: Endpoint, state_dir: Path, ports: list[int], period_s: float, same_plan: bool = False) -> str:
    return (f"mqtt:\n  host: {broker.host}\n  port: {broker.port}\n  formats: [sparkplug]\n"
            f"  sparkplug: {{group_id: {GROUP}, edge_node_id: gw}}\n"
            f"state_dir: {state_dir}\nmachines:\n{machines_section(ports, period_s, same_plan)}")


def wait_until(condition: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout:.0f}s waiting for {what}")
        time.sleep(0.05)


def run_fleet(options: FleetOptions) -> dict[str, Any]:
    """One measurement at one fleet size; every process it starts is stopped before it returns."""
    binary = mosquitto_binary()
    if binary is None:
        raise RuntimeError("mosquitto is not installed (make bench runs scripts/ensure-mosquitto.sh)")
    workdir = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    broker = Mosquitto(binary)
    sims: list[SimProcess] = []
    daemon: DaemonProcess | None = None
    subscriber: LatencySubscriber | None = None
    try:
        broker.start()
        broker_process = psutil.Process(broker.proc.pid) if broker.proc else None
        subscriber = LatencySubscriber(broker.host, broker.port, GROUP, f"Macro/{STAMP_MACRO}",
                                       f"Macro/{CLOCK_MACRO}",
                                       cnc_offset=None if options.same_clock else device_clock_offset)
        n = options.machines
        sims = start_fleet_sims(n, options.period_s, spread_clocks=not options.same_clock)
        ports = [port for sim in sims for port in sim.ports]
        config = workdir / "edge.yaml"
        config.write_text(config_text(broker, workdir / "state", ports, options.period_s, options.same_plan))
        started = time.time()
        diagnosis = workdir / "diagnosis.json" if options.diagnose else None
        daemon = DaemonProcess(config, workdir / "daemon.log", options.profile_to, options.tracemalloc_to,
                               diagnosis, spread_clocks=not options.same_clock)
        born_s = wait_for_births(subscriber, daemon, n, started, workdir)
        # Start-up: the daemon's CPU until the last birth, and how long its loop thread ran and waited for a CPU
        born_cpu_s, (born_ran_s, born_waited_s) = daemon.cpu_seconds(), daemon.loop_schedstat()
        time.sleep(options.warmup_s)
        measured = _window(options, daemon, sims, subscriber, broker_process, diagnosis)
        measured["deaths"] = subscriber.deaths
        measured["all_born_s"] = born_s
        measured.update(born_cpu_s=born_cpu_s, born_loop_ran_s=born_ran_s, born_loop_waited_s=born_waited_s)
        if options.tracemalloc_to is not None:
            dump_allocations(daemon, options.tracemalloc_to)
        return measured
    finally:
        if daemon is not None:
            code = daemon.stop(timeout=15)
            if code not in (0, None) and options.profile_to is None:
                print(f"warning: daemon exit code {code} (not stopped by SIGTERM within 15 s, killed)")
        for sim in sims:
            sim.stop()
        if subscriber is not None:
            subscriber.close()
        broker.close()
        if options.profile_to is None:
            shutil.rmtree(workdir, ignore_errors=True)


def wait_for_births(subscriber: LatencySubscriber, daemon: DaemonProcess, machines: int, started: float,
                    workdir: Path) -> float:
    """Seconds from the daemon's start to the last of `machines` first DBIRTHs (issue 25: <= 30 s at 1,000)."""
    try:
        wait_until(lambda: len(subscriber.births) >= machines or daemon.proc.poll() is not None,
                   30 + machines * 0.2, f"DBIRTH of {machines} machines")
    except RuntimeError as exc:
        raise RuntimeError(f"{exc} ({len(subscriber.births)} born)") from None
    if daemon.proc.poll() is not None:
        raise RuntimeError(f"daemon exited with {daemon.proc.returncode}; see {workdir / 'daemon.log'}")
    return max(subscriber.birth_times.values()) - started


def dump_allocations(daemon: DaemonProcess, out: Path) -> None:
    """Ask the daemon under bench.memory_daemon for its allocations by module and wait until they are written."""
    out.unlink(missing_ok=True)
    daemon.proc.send_signal(signal.SIGUSR1)
    wait_until(lambda: out.exists() and out.stat().st_size > 0, 120, f"the tracemalloc snapshot in {out}")
    time.sleep(0.5)  # the writer's last bytes


def start_fleet_sims(machines: int, period_s: float = 0.1, spread_clocks: bool = False) -> list[SimProcess]:
    """The fleet's simulated CNCs, spread over processes (each stamps the latency macro); with `spread_clocks`
    each CNC clock its own offset (bench.clocks), else every one this host's.

    A process takes MACHINES_PER_SIM machines, or at a slow period as many as make SIM_REQUESTS_PER_S (at most
    MAX_MACHINES_PER_SIM): an idle simulator process wakes cold for every request, so twenty of them answering
    50 requests a second each cost ~500 us of CPU per request where five answering 200 each cost ~370 us.
    """
    per_sim = max(MACHINES_PER_SIM, min(MAX_MACHINES_PER_SIM, round(SIM_REQUESTS_PER_S * period_s)))
    parts = math.ceil(machines / per_sim)
    size = math.ceil(machines / parts)
    sims: list[SimProcess] = []
    try:
        for first in range(0, machines, size):
            sims.append(SimProcess(min(size, machines - first), stamp_macro=STAMP_MACRO, clock_macro=CLOCK_MACRO,
                                   spread_clocks_from=first if spread_clocks else None))
    except BaseException:
        for sim in sims:
            sim.stop()
        raise
    return sims


def _window(options: FleetOptions, daemon: DaemonProcess, sims: list[SimProcess],
            subscriber: LatencySubscriber, broker: psutil.Process | None,
            diagnosis: Path | None = None) -> dict[str, Any]:
    if diagnosis is not None:
        daemon.proc.send_signal(signal.SIGUSR1)  # bench.latency_daemon: a fresh window
    psutil.cpu_percent(None)
    host_before = psutil.cpu_times()
    subscriber.take()
    subscriber.recording = True
    overruns_before = subscriber.overruns or 0
    sims_before = [sim.stats() for sim in sims]
    cpu_before = daemon.cpu_seconds()
    sys_before = daemon.system_seconds()
    switches_before = daemon.context_switches()
    broker_before = _cpu(broker)
    bench_process = psutil.Process()
    subscriber_before = _cpu(bench_process)  # the subscriber's network thread; the main thread only samples RSS
    spy = None
    if options.spy_to is not None:
        spy = subprocess.Popen([options.py_spy, "record", "--pid", str(daemon.proc.pid), "--rate", "250",
                                "--duration", str(int(options.duration_s)), "--format", "raw", "--threads",
                                "--nonblocking", "-o", str(options.spy_to)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    started = time.monotonic()
    rss: list[int] = []
    while time.monotonic() - started < options.duration_s:
        rss.append(daemon.rss_bytes())
        time.sleep(min(1.0, max(0.0, options.duration_s - (time.monotonic() - started))))
    elapsed = time.monotonic() - started
    cpu = daemon.cpu_seconds() - cpu_before
    sys_cpu = daemon.system_seconds() - sys_before
    switches = daemon.context_switches() - switches_before
    sims_after = [sim.stats() for sim in sims]
    subscriber_cpu = _cpu(bench_process) - subscriber_before
    subscriber.recording = False
    diagnosed = read_diagnosis(daemon, diagnosis) if diagnosis is not None else None
    rss.append(daemon.rss_bytes())
    system_cpu = psutil.cpu_percent(None)
    host_after = psutil.cpu_times()
    if spy is not None:
        spy.wait(30)
    errors = subscriber.take_stamp_errors()
    in_gateway, to_subscriber = subscriber.take_sample_split()
    values, messages = subscriber.take_value_counts()
    change, sample = subscriber.take()
    clock_reads = sum(a.get("clock_pdus", 0) - b.get("clock_pdus", 0)
                      for a, b in zip(sims_after, sims_before, strict=True))
    cycles = sum(a["data_pdus"] - b["data_pdus"] for a, b in zip(sims_after, sims_before, strict=True)) - clock_reads
    magnitudes = [abs(e) for e in errors]
    sim_cpu = sum(a["cpu_s"] - b["cpu_s"] for a, b in zip(sims_after, sims_before, strict=True))
    planned = options.machines / options.period_s
    return {
        "machines": options.machines,
        "period_s": options.period_s,
        "cpu_us_per_cycle": cpu / cycles * 1e6 if cycles else float("nan"),
        "sys_us_per_cycle": sys_cpu / cycles * 1e6 if cycles else float("nan"),
        "wakeups_per_cycle": switches / cycles if cycles else float("nan"),
        "gateway_cores": cpu / elapsed,
        "rss_mb": max(rss) / 1e6,
        "cycles_per_s": cycles / elapsed,
        "planned_per_s": planned,
        "achieved_pct": 100 * cycles / elapsed / planned,
        "overruns": (subscriber.overruns or 0) - overruns_before,
        "change_p50_ms": percentile(change, 50) * 1000,
        "change_p99_ms": percentile(change, 99) * 1000,
        "changes_seen": len(change),
        "sample_p50_ms": percentile(sample, 50) * 1000,
        "sample_p99_ms": percentile(sample, 99) * 1000,
        "in_gateway_p99_ms": percentile(in_gateway, 99) * 1000,
        "to_subscriber_p99_ms": percentile(to_subscriber, 99) * 1000,
        "stamp_err_p50_ms": percentile(errors, 50) * 1000,
        "stamp_abs_p99_ms": percentile(magnitudes, 99) * 1000,
        "stamp_abs_max_ms": max(magnitudes, default=float("nan")) * 1000,
        "stamps_seen": len(errors),
        "clock_reads_per_machine_min": clock_reads / options.machines / elapsed * 60,
        "sim_cores": sim_cpu / elapsed,
        "broker_cores": (_cpu(broker) - broker_before) / elapsed,
        "subscriber_cores": subscriber_cpu / elapsed,
        "host_cpu_pct": system_cpu,
        "steal_pct": _steal_pct(host_before, host_after),
        "window_s": elapsed,
        "fds": daemon.open_fds(),
        "values_per_cycle": values / cycles if cycles else float("nan"),
        "values_per_message": values / messages if messages else float("nan"),
        **({"diagnosis": diagnosed} if diagnosed is not None else {}),
    }


def diagnosis_line(d: dict[str, Any]) -> str:
    """One line of bench.latency_daemon's figures: what held the loop, and for how long."""
    gc_all, lag, slots = d["gc"]["all"], d["loop_lag"], d["machines_per_slot"]
    return (f"loop thread ran {d.get('loop_thread_ran_s', 0):.1f} s, waited for a CPU "
            f"{d.get('loop_thread_waited_s', 0):.1f} s of {d['window_s']:.0f} s; "
            f"loop lag p50/p99/max {lag.get('p50_ms', 0):.1f}/{lag.get('p99_ms', 0):.1f}/"
            f"{lag.get('max_ms', 0):.0f} ms; "
            f"gc {gc_all['n']} collections, {gc_all.get('sum_ms', 0):.0f} ms, max {gc_all.get('max_ms', 0):.0f} ms "
            f"(gen2 {d['gc']['gen2']['n']}), {d['gc_tracked_objects']} tracked, {d['gc_frozen_objects']} frozen; "
            f"machines per slot {slots.get('min')}..{slots.get('max')} (mean {slots.get('mean', 0):.1f}); "
            f"stamp->outputs p50/p99 {d['stamp_to_outputs'].get('p50_ms', 0):.0f}/"
            f"{d['stamp_to_outputs'].get('p99_ms', 0):.0f} ms; tick p99 {d['tick'].get('p99_ms', 0):.0f} ms"
            + clock_line(d.get("clock", {})))


def clock_line(c: dict[str, Any]) -> str:
    """The clock offset's share of the stamp error (bench.latency_daemon): per tick and per machine."""
    if not c:
        return ""
    tick, machine, unc = c["tick_offset_error_abs"], c["machine_offset_error_abs"], c["machine_uncertainty"]
    return (f"; clock offset error p50/p99/max per tick {tick.get('p50_ms', 0):.1f}/{tick.get('p99_ms', 0):.1f}/"
            f"{tick.get('max_ms', 0):.0f} ms, per machine p99 {machine.get('p99_ms', 0):.1f} ms; uncertainty "
            f"p50/p99/max {unc.get('p50_ms', 0):.1f}/{unc.get('p99_ms', 0):.1f}/{unc.get('max_ms', 0):.0f} ms; "
            f"clock-only reads per machine {c['probes_sent_per_machine']['mean']:.1f} (max "
            f"{c['probes_sent_per_machine']['max']:.0f})")


def read_diagnosis(daemon: DaemonProcess, out: Path) -> dict[str, Any]:
    """The window's loop lag, GC pauses and grid slots from bench.latency_daemon (SIGUSR2 writes them)."""
    out.unlink(missing_ok=True)
    daemon.proc.send_signal(signal.SIGUSR2)
    wait_until(lambda: out.exists() and out.stat().st_size > 0, 30, f"the latency diagnosis in {out}")
    time.sleep(0.2)  # the writer's last bytes
    return dict(json.loads(out.read_text()))


def _steal_pct(before: Any, after: Any) -> float:
    """CPU time the hypervisor gave to other guests: the VM's noise, shown beside every figure."""
    total = sum(after) - sum(before)
    return 100 * (getattr(after, "steal", 0.0) - getattr(before, "steal", 0.0)) / total if total > 0 else 0.0


def _cpu(process: psutil.Process | None) -> float:
    if process is None:
        return 0.0
    times = process.cpu_times()
    return float(times.user + times.system)


SUMMARY_KEYS = ("all_born_s", "born_cpu_s", "born_loop_ran_s", "born_loop_waited_s", "cpu_us_per_cycle",
                "sys_us_per_cycle", "wakeups_per_cycle", "gateway_cores", "rss_mb",
                "cycles_per_s", "achieved_pct", "overruns", "change_p50_ms", "change_p99_ms", "sample_p50_ms",
                "sample_p99_ms", "in_gateway_p99_ms", "to_subscriber_p99_ms", "stamp_err_p50_ms",
                "stamp_abs_p99_ms", "stamp_abs_max_ms", "stamps_seen",
                "clock_reads_per_machine_min", "sim_cores", "broker_cores", "subscriber_cores", "host_cpu_pct",
                "steal_pct", "fds",
                "values_per_cycle", "values_per_message")


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Median of each figure over repeated runs, plus the spread of the CPU figure."""
    row: dict[str, Any] = {"machines": runs[0]["machines"], "period_s": runs[0]["period_s"], "runs": len(runs)}
    for key in SUMMARY_KEYS:
        values = [r[key] for r in runs if not (isinstance(r[key], float) and math.isnan(r[key]))]
        row[key] = statistics.median(values) if values else float("nan")
    cpu = [r["cpu_us_per_cycle"] for r in runs]
    row["cpu_us_range"] = f"{min(cpu):.0f}..{max(cpu):.0f}"
    row["planned_per_s"] = runs[0]["planned_per_s"]
    if "diagnosis" in runs[0]:
        row["diagnosis"] = runs[0]["diagnosis"]
    return row


def run(quick: bool = False, sizes: list[int] | None = None, repeats: int = 2, duration_s: float | None = None,
        spy_to: Path | None = None, py_spy: str = "py-spy", periods: list[float] | None = None,
        warmup_s: float | None = None, tracemalloc_to: Path | None = None, diagnose: bool = False,
        same_plan: bool = False, same_clock: bool = False) -> Result:
    sizes = sizes or ([5, 20] if quick else [10, 50, 100, 200])
    periods = periods or [0.1]
    duration = duration_s or (5.0 if quick else 20.0)
    warmup = warmup_s if warmup_s is not None else (1.0 if quick else FleetOptions.warmup_s)
    repeats = 1 if quick else repeats
    command = (f"python -m bench fleet{' --quick' if quick else ''} --sizes {','.join(map(str, sizes))} "
               f"--period {','.join(f'{p:g}' for p in periods)} --repeat {repeats} --duration {duration:g}"
               f"{f' --warmup {warmup:g}' if warmup_s is not None else ''}{' --diagnose' if diagnose else ''}"
               f"{' --same-plan' if same_plan else ''}{' --same-clock' if same_clock else ''}")
    result = Result("fleet", command)
    extra = {"diagnose": diagnose, "same_plan": same_plan, "same_clock": same_clock}
    for period in periods:
        _run_period(result, period, sizes, repeats, duration, warmup, spy_to, py_spy, tracemalloc_to, extra)
    return result


def _run_period(result: Result, period: float, sizes: list[int], repeats: int, duration: float, warmup: float,
                spy_to: Path | None, py_spy: str, tracemalloc_to: Path | None = None,
                extra: dict[str, bool] | None = None) -> None:
    """Every fleet size at one poll period: rows and target checks into `result`."""
    by_size: dict[int, dict[str, Any]] = {}
    for n in sizes:
        first_of_biggest = [n == max(sizes) and i == 0 for i in range(repeats)]
        runs = [run_fleet(FleetOptions(n, period_s=period, duration_s=duration, warmup_s=warmup,
                                       spy_to=spy_to if first else None, py_spy=py_spy,
                                       tracemalloc_to=tracemalloc_to if first else None,
                                       diagnose=bool(extra and extra["diagnose"]),
                                       same_plan=bool(extra and extra["same_plan"]),
                                       same_clock=bool(extra and extra["same_clock"])))
                for first in first_of_biggest]
        by_size[n] = summarise(runs)
        result.rows.append(by_size[n])
        print(f"  fleet N={n} period {period:g}s: {by_size[n]['cpu_us_per_cycle']:.0f} us/cycle, "
              f"{by_size[n]['achieved_pct']:.0f}% of plan, change p99 {by_size[n]['change_p99_ms']:.0f} ms, "
              f"stamp error p99 {by_size[n]['stamp_abs_p99_ms']:.1f} ms", flush=True)
        if "diagnosis" in by_size[n]:
            print(f"  diagnosis N={n}: {diagnosis_line(by_size[n]['diagnosis'])}", flush=True)
    biggest = max(by_size)
    at = 100 if 100 in by_size else biggest
    where = f"{at} machines x {period:g} s"
    # The target is stated at scale ("100 machines at 10 Hz in under a sixth of one core"); a small fleet
    # carries the process's fixed costs over few cycles, so the worst size is shown beside it, not hidden.
    result.checks.append(Check(f"gateway CPU per machine-cycle at {where}", by_size[at]["cpu_us_per_cycle"],
                               CPU_TARGET_US, "<=", " us"))
    worst = max(by_size, key=lambda n: by_size[n]["cpu_us_per_cycle"])
    result.notes.append(f"highest CPU per machine-cycle at {period:g} s: {by_size[worst]['cpu_us_per_cycle']:.0f} us "
                        f"at {worst} machines ({by_size[worst]['gateway_cores']:.2f} cores: the process's fixed costs)")
    big = biggest >= LARGE_FLEET
    result.checks.append(Check(f"RSS with {biggest} machines x {period:g} s", by_size[biggest]["rss_mb"],
                               LARGE_RSS_TARGET_MB if big else RSS_TARGET_MB, "<=", " MB"))
    if big:
        where_big = f"{biggest} machines x {period:g} s"
        result.checks.append(Check(f"sample (CNC stamp to broker receipt) p99 at {where_big}",
                                   by_size[biggest]["sample_p99_ms"], LARGE_SAMPLE_P99_MS, "<=", " ms"))
        result.checks.append(Check(f"every DBIRTH after the daemon's start, {biggest} machines",
                                   by_size[biggest]["all_born_s"], LARGE_BIRTHS_S, "<=", " s"))
    result.checks.append(Check(f"change-to-broker p99 at {where}", by_size[at]["change_p99_ms"],
                               (period + LATENCY_SLACK_S) * 1000, "<=", " ms"))
    result.checks.append(Check(f"CNC timestamp error p99 at {where}", by_size[at]["stamp_abs_p99_ms"],
                               STAMP_TARGET_MS, "<=", " ms"))
    if result.notes:
        return
    result.notes.append("cycles = data PDUs the simulators answered, clock-only reads not counted; CPU = user+sys "
                        "of the daemon process only")
    result.notes.append("change = simulator sets a macro to its clock -> subscriber receipt (includes up to one "
                        "poll period of waiting); sample = CNC timestamp of the tick -> receipt")
    result.notes.append("stamp = a value's CNC timestamp minus the simulator's clock when it answered that read "
                        "(p50 signed, p99 and max of the magnitude); clock reads = clock-only requests between "
                        "ticks, per machine per minute")
    result.notes.append("sample split at the DDATA's payload timestamp (the gateway's clock when it encoded it): "
                        "in_gateway = CNC stamp -> encoded, to_subscriber = encoded -> received")
