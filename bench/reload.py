"""Start-up and reload at scale (issue 25 point 4): N simulated CNCs -> the daemon -> mosquitto.

Measures the seconds from the daemon's start to the last machine's first DBIRTH, then adds one machine
to the config file and sends SIGHUP: the seconds to the new machine's DBIRTH, and over the following
window whether any other machine was disturbed: a second DBIRTH or a DDEATH of any other machine, a gap
in the node's seq (every Sparkplug message of the node, checked by the subscriber), a machine that
stopped publishing DDATA.

    python -m bench reload --sizes 1000 [--period 1] [--duration 20]
"""

from __future__ import annotations

import contextlib
import shutil
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.fleet import GROUP, config_text, start_fleet_sims, wait_for_births, wait_until
from bench.procs import DaemonProcess, running_broker, stop_sims
from bench.report import Check, Result
from bench.subscriber import LatencySubscriber
from bench.workload import CLOCK_MACRO, STAMP_MACRO
from tests.helpers import Mosquitto

BIRTHS_TARGET_S = 30.0
SETTLE_S = 10.0  # after the last birth, before the reload: the start-up's clock reads are over


def run_reload(machines: int, period_s: float, watch_s: float) -> dict[str, Any]:
    """One start plus one reload adding a machine; every process it starts is stopped before it returns."""
    with contextlib.ExitStack() as stack:
        workdir = Path(tempfile.mkdtemp(prefix="bench-reload-"))
        outcome: dict[str, Any] = {}
        stack.callback(_tidy, workdir, outcome)
        broker = stack.enter_context(running_broker())
        subscriber = LatencySubscriber(broker.host, broker.port, GROUP, f"Macro/{STAMP_MACRO}",
                                       f"Macro/{CLOCK_MACRO}", track_seq=True)
        stack.callback(subscriber.close)
        sims = start_fleet_sims(machines + 1, period_s)
        stack.callback(stop_sims, sims)
        ports = [port for sim in sims for port in sim.ports]
        config = workdir / "edge.yaml"
        config.write_text(config_text(broker, workdir / "state", ports[:machines], period_s))
        started = time.time()
        daemon = DaemonProcess(config, workdir / "daemon.log")
        stack.callback(daemon.stop, timeout=30)
        born_s = wait_for_births(subscriber, daemon, machines, started, workdir)
        time.sleep(SETTLE_S)
        outcome.update({"machines": machines, "period_s": period_s, "all_born_s": born_s,
                        **_reload(subscriber, daemon, config, broker, workdir, ports, period_s, watch_s)})
        return outcome


def _tidy(workdir: Path, outcome: dict[str, Any]) -> None:
    """The work dir (daemon log, config) is kept when the run failed or disturbed a machine."""
    if outcome and not any(outcome[k] for k in ("other_dbirths", "ddeaths", "seq_gaps", "silent_machines")):
        shutil.rmtree(workdir, ignore_errors=True)
    else:
        print(f"  reload: logs kept in {workdir}", flush=True)


def _reload(subscriber: LatencySubscriber, daemon: DaemonProcess, config: Path, broker: Mosquitto, workdir: Path,
            ports: list[int], period_s: float, watch_s: float) -> dict[str, Any]:
    machines = len(ports) - 1
    added = f"m{machines + 1:03d}"
    births_before = sum(subscriber.dbirths.values())
    deaths_before = subscriber.deaths
    gaps_before = len(subscriber.seq_gaps)
    config.write_text(config_text(broker, workdir / "state", ports, period_s))
    sent = time.time()
    daemon.proc.send_signal(signal.SIGHUP)
    wait_until(lambda: added in subscriber.birth_times, 120, f"the DBIRTH of {added}")
    added_born_s = subscriber.birth_times[added] - sent
    data_before = dict(subscriber.ddata)
    time.sleep(watch_s)
    silent = [d for d, count in subscriber.ddata.items() if d != added and count <= data_before.get(d, 0)]
    return {"added_born_s": added_born_s,
            "other_dbirths": sum(subscriber.dbirths.values()) - births_before - 1,
            "ddeaths": subscriber.deaths - deaths_before,
            "seq_gaps": len(subscriber.seq_gaps) - gaps_before,
            "seq_gaps_before_reload": gaps_before,
            "silent_machines": len(silent),
            "watch_s": watch_s}


def run(sizes: list[int] | None = None, period_s: float | None = None, duration_s: float | None = None,
        quick: bool = False) -> Result:
    sizes = sizes or ([20] if quick else [1000])
    period = period_s or 1.0
    watch = duration_s or (5.0 if quick else 20.0)
    result = Result("reload", f"python -m bench reload --sizes {','.join(map(str, sizes))} --period {period:g} "
                              f"--duration {watch:g}")
    for n in sizes:
        row = run_reload(n, period, watch)
        result.rows.append(row)
        print(f"  reload N={n}: all born in {row['all_born_s']:.1f} s, added born in {row['added_born_s']:.2f} s, "
              f"other DBIRTHs {row['other_dbirths']}, DDEATHs {row['ddeaths']}, seq gaps {row['seq_gaps']}",
              flush=True)
        result.checks.append(Check(f"every DBIRTH after the daemon's start, {n} machines", row["all_born_s"],
                                   BIRTHS_TARGET_S, "<=", " s"))
        for key, what in (("other_dbirths", "other machines reborn"), ("ddeaths", "DDEATHs"),
                          ("seq_gaps", "gaps in the node's seq"), ("silent_machines", "machines gone quiet")):
            result.checks.append(Check(f"{what} by a reload adding one machine to {n}", row[key], 0, "<="))
    result.notes.append("seq gaps counted on every Sparkplug message of the node from the reload to the end of the "
                        "window; a machine gone quiet published no DDATA in that window")
    return result
