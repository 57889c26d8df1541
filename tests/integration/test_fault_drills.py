"""CNC fault drills: every simulator fault on one machine ends in DDEATH, backoff and DBIRTH on recovery,
while the other machines keep publishing on time; a function a control refuses is dropped from its plan.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, Machine, MachineSpec
from edge.sim.native_server import ServerStats
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.delivery import keep_changing
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

REQUEST_TIMEOUT_S = 1.0
ON_TIME_S = 0.5  # the healthy machines' longest allowed gap between ticks (status polled every 0.1 s)


def config_text(broker: Mosquitto, state_dir: Path, fleet: Fleet) -> str:
    machines = "".join(
        f"  - {{id: m{i + 1}, host: 127.0.0.1, port: {m.port}, "
        f"poll: {{periods: {{status: 0.1s, macros: 0.1s}}, macros: [500]}}, "
        f"timeouts: {{request_s: {REQUEST_TIMEOUT_S}, connect_s: 1, backoff_initial_s: 0.1, "
        f"backoff_max_s: 0.5}}}}\n" for i, m in enumerate(fleet))
    return daemon_config(broker, state_dir, machines)


@dataclass
class Silence:
    """The longest gap between poll ticks, and between DDATA messages, of each watched machine."""

    daemon: Daemon
    observer: Observer
    devices: list[str]
    longest: dict[str, float] = field(default_factory=dict)  # between ticks
    longest_ddata: dict[str, float] = field(default_factory=dict)  # between DDATA (only sent on change)

    async def watch(self) -> None:
        last: dict[str, tuple[int, float]] = {}
        last_data: dict[str, tuple[int, float]] = {}
        while True:
            now = time.monotonic()
            for d in self.devices:
                for table, longest, count in (
                        (last, self.longest, self.daemon.pollers[d].stats.ticks),
                        (last_data, self.longest_ddata, len(self.observer.on(f"spBv1.0/plant/DDATA/gw/{d}")))):
                    before = table.get(d)
                    if before is None or count != before[0]:
                        table[d] = (count, now)
                    longest[d] = max(longest.get(d, 0.0), now - table[d][1])
            await asyncio.sleep(0.02)


@dataclass
class Fault:
    name: str
    inject: Callable[[Machine], None]
    recover: Callable[[Machine], None] = lambda m: m.faults.clear()


def _refuse(m: Machine) -> None:
    m.faults.update({"refuse": -1})
    m.drop_connections()


def _max_sessions(m: Machine) -> None:
    m.faults.update({"max_sessions": 0})
    m.drop_connections()


SELF_CLEARING = {"drop mid-session", "hang mid-frame (no FIN)", "garbage bytes"}  # counted faults
FAULTS = [
    Fault("refused connect", _refuse),
    Fault("drop mid-session", lambda m: m.faults.update({"drop_after": 1})),
    Fault("hang mid-frame (no FIN)", lambda m: m.faults.update({"hang": 1})),
    Fault("garbage bytes", lambda m: m.faults.update({"garbage": 1})),
    Fault("slow responses past the timeout", lambda m: m.faults.update({"latency": REQUEST_TIMEOUT_S * 1.5})),
    Fault("too many sessions", _max_sessions),
]


async def test_each_cnc_fault_ends_in_ddeath_backoff_dbirth_while_others_publish_on_time(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i") for _ in range(3)], base_port=0) as fleet:
        daemon = Daemon(parse_config(config_text(mosquitto, tmp_path, fleet)))
        task = asyncio.create_task(daemon.run())
        silence = Silence(daemon, observer, ["m2", "m3"])
        watcher: asyncio.Task[None] | None = None
        changer = asyncio.create_task(keep_changing(list(fleet)))
        figures: dict[str, float] = {}
        try:
            for d in ("m1", "m2", "m3"):
                await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/{d}", timeout=15)
            watcher = asyncio.create_task(silence.watch())
            target = fleet[0]
            for n, fault in enumerate(FAULTS, start=1):
                refused_before = target.native.stats.refused
                others_before = {d: len(observer.on(f"spBv1.0/plant/DDATA/gw/{d}")) for d in ("m2", "m3")}
                injected = time.monotonic()
                fault.inject(target)
                await observer.wait_topic("spBv1.0/plant/DDEATH/gw/m1", count=n, timeout=15)
                dead = time.monotonic()
                if fault.name == "refused connect":
                    enough = refused_before + 3

                    def retried(stats: ServerStats = target.native.stats, enough: int = enough) -> bool:
                        return stats.refused >= enough

                    await async_wait_for(retried, timeout=10, message="reconnect attempts")
                    window_start, refused_start = time.monotonic(), target.native.stats.refused
                    await asyncio.sleep(2.0)  # a backoff window: attempts must be paced, not a busy loop
                    rate = (target.native.stats.refused - refused_start) / (time.monotonic() - window_start)
                    assert 0 < rate < 25, f"{fault.name}: {rate:.1f} connect attempts/s is no backoff"
                    figures["refused_attempts_per_s"] = round(rate, 1)
                if fault.name not in SELF_CLEARING:
                    assert daemon.pollers["m1"].online is False, f"{fault.name}: back before recovery"
                fault.recover(target)
                await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=n + 1, timeout=15)
                figures[fault.name] = round(time.monotonic() - dead, 2)
                figures[f"{fault.name} detect"] = round(dead - injected, 2)
                for d, before in others_before.items():
                    # m1 can come back within one of m2's poll periods (a dropped socket reconnects at once),
                    # so wait a little for the others' next DATA; `silence` checks the gaps themselves.
                    def published(d: str = d, before: int = before) -> bool:
                        return len(observer.on(f"spBv1.0/plant/DDATA/gw/{d}")) > before

                    await async_wait_for(published, timeout=3, message=f"{d} silent: {fault.name}")
            before_stop = observer.snapshot()
        finally:
            changer.cancel()
            if watcher is not None:
                watcher.cancel()
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
        # Order per fault: DDEATH, then (no data), then DBIRTH.
        m1 = [m.kind for m in before_stop if m.topic.endswith("/gw/m1")]
        deaths = [i for i, k in enumerate(m1) if k == "DDEATH"]
        for i in deaths:
            rebirth = m1.index("DBIRTH", i)
            assert "DDATA" not in m1[i:rebirth]
        assert len(deaths) == len(FAULTS)
        for d in ("m2", "m3"):
            assert silence.longest[d] < ON_TIME_S, f"{d} did not poll for {silence.longest[d]:.2f}s during faults"
            quiet = silence.longest_ddata[d]
            assert quiet < 2 * ON_TIME_S, f"{d} published nothing for {quiet:.2f}s"
            assert not [m for m in before_stop if m.topic == f"spBv1.0/plant/DDEATH/gw/{d}"]
        print(f"\nFIGURES cnc faults (s from DDEATH to DBIRTH, detection): {json.dumps(figures)} "
              f"longest_tick_gap_others={max(silence.longest.values()):.2f} "
              f"longest_ddata_gap_others={max(silence.longest_ddata.values()):.2f}")


async def test_function_answering_ew_func_is_dropped_from_the_plan_once(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="edge.collect.poller")
    async with Fleet([MachineSpec(profile="30i", faults={"ew": {"spindle_load": 1}}), MachineSpec(profile="30i")],
                     base_port=0) as fleet:
        daemon = Daemon(parse_config(config_text(mosquitto, tmp_path, fleet)))
        task = asyncio.create_task(daemon.run())
        try:
            await observer.wait_topic("focas/m1/state/Plan/DroppedFunctions", timeout=15)

            def dropped() -> str:
                docs = [json.loads(m.payload) for m in observer.on("focas/m1/state/Plan/DroppedFunctions")]
                return str(docs[-1]["value"]) if docs else ""

            await async_wait_for(lambda: "SpindleLoad" in dropped(), timeout=10, message="the metric names it")
            ticks = daemon.pollers["m1"].stats.ticks
            await async_wait_for(lambda: daemon.pollers["m1"].stats.ticks > ticks + 20, timeout=10,
                                 message="more ticks")
            deaths = observer.on("spBv1.0/plant/DDEATH/gw/m1")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
    lines = [r for r in caplog.records if "dropped from plan" in r.getMessage() and "machine=m1" in r.getMessage()]
    assert len(lines) == 1, [r.getMessage() for r in lines]
    assert "machine=m2" not in caplog.text or "dropped from plan machine=m2" not in caplog.text
    assert not deaths, "the machine stayed online"
    errors = daemon.pollers["m1"].stats.item_errors
    assert sum(errors.values()) == 1, f"the function failed once, not every tick: {errors}"


async def test_one_refused_position_kind_drops_only_that_kind(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """A control answering EW_NOOPT for distance-to-go (as a real EDM does) keeps publishing the other
    position kinds; only ReadPositions:distance is dropped."""
    async with Fleet([MachineSpec(profile="30i", faults={"ew": {"positions/7": 6}})], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, "
                    f"poll: {{periods: {{status: 0.1s}}, positions: [absolute, distance]}}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines)))
        task = asyncio.create_task(daemon.run())
        try:
            def dropped() -> str:
                docs = [json.loads(m.payload) for m in observer.on("focas/m1/state/Plan/DroppedFunctions")]
                return str(docs[-1]["value"]) if docs else ""

            await async_wait_for(lambda: dropped() == "ReadPositions:distance", timeout=15,
                                 message="only the distance kind is dropped")
            seen = len(observer.on("focas/m1/state/Axis/X/Absolute"))
            await async_wait_for(lambda: len(observer.on("focas/m1/state/Axis/X/Absolute")) > seen + 2,
                                 timeout=15, message="absolute positions keep coming")
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0
