"""Store and forward end to end: simulator -> daemon -> (relay) -> real mosquitto -> subscriber.

The daemon reaches the broker through a TCP relay, so a drill can keep the daemon away from a broker that
is already back for the test's own subscriber (which must not miss the daemon's first messages), or
swallow traffic without closing anything (a dead link the daemon has to *suspect*).

DRILL_OUTAGE_S sets the broker outage (default 6 s here; docs/reliability.md has the 30 s figures).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import sqlite3
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.publish import payload as pl
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.json_topics import GATEWAY, OFFLINE
from edge.publish.sparkplug_b_pb2 import Payload
from edge.publish.spool_rows import decode_samples
from edge.samples import MetricType, Sample
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.delivery import (
    Collected,
    changing_fleet,
    compare,
    json_arrivals,
    key_of,
    sparkplug_arrivals,
)
from tests.integration.mqtt_observer import Observer
from tests.integration.tcp_relay import TcpRelay
from tests.small_disk import fill, small_disk

pytestmark = pytest.mark.integration

OUTAGE_S = float(os.environ.get("DRILL_OUTAGE_S", "6"))
MACHINES = 5
FAST = ForwardingPolicy(probe_interval_s=0.3, probe_timeout_s=1.5, replay_rows_per_s=200)


def config_text(host: str, port: int, state_dir: Path, fleet: Fleet, sparkplug_extra: str = "") -> str:
    machines = "".join(
        f"  - {{id: m{i + 1}, host: 127.0.0.1, port: {m.port}, "
        f"poll: {{periods: {{status: 0.1s, macros: 0.1s}}, macros: [500]}}, "
        f"timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.5}}}}\n"
        for i, m in enumerate(fleet))
    return f"""
mqtt:
  host: {host}
  port: {port}
  keepalive: 5
  formats: [sparkplug, json]
  sparkplug: {{group_id: plant, edge_node_id: gw{sparkplug_extra}}}
  json: {{prefix: focas}}
state_dir: {state_dir}
machines:
{machines}"""


@pytest.fixture
async def fleet() -> AsyncIterator[Fleet]:
    async with changing_fleet(MACHINES) as f:
        yield f

async def start(text: str, policy: ForwardingPolicy = FAST) -> tuple[Daemon, asyncio.Task[int], Collected]:
    daemon = Daemon(parse_config(text))
    daemon.publisher.forwarding = policy
    daemon.publisher.settings.reconnect_min_s = 0.1
    daemon.publisher.settings.reconnect_max_s = 0.5
    collected = Collected()
    collected.spy_on(daemon.publisher)
    return daemon, asyncio.create_task(daemon.run()), collected


async def stop(daemon: Daemon, task: asyncio.Task[int]) -> None:
    daemon.request_stop()
    assert await asyncio.wait_for(task, 20) == 0


def birth_aliases(observer: Observer, device: str) -> dict[str, int]:
    birth = observer.on(f"spBv1.0/plant/DBIRTH/gw/{device}")[-1].spb()
    return {m.name: m.alias for m in birth.metrics}


async def all_born(observer: Observer, count: int = 1) -> None:
    for i in range(MACHINES):
        await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/m{i + 1}", count=count, timeout=20)


async def broker_back(mosquitto: Mosquitto, relay: TcpRelay, observer: Observer, collected: Collected,
                      daemon: Daemon) -> tuple[int, float]:
    """Restart the broker, let the daemon in once the test's subscriber is back: (rows waiting, when)."""
    mosquitto.start()
    await observer.wait_resubscribed()
    collected.phase = "replay"
    waiting = daemon.spool.pending()
    reopened = time.monotonic()
    relay.accepting = True
    await all_born(observer, count=2)
    return waiting, reopened


async def wait_delivered(observer: Observer, collected: Collected) -> None:
    """Wait until every collected sample arrived in both formats (or fail with what is missing)."""

    def missing() -> bool:
        snap = observer.snapshot()
        return not compare(collected, sparkplug_arrivals(snap, "plant", "gw")).missing and \
            not compare(collected, json_arrivals(snap, "focas")).missing

    with contextlib.suppress(AssertionError):  # the assertions after this say what is missing
        await async_wait_for(missing, timeout=30, interval=0.2, message="every collected sample delivered")


def assert_no_loss(observer: Observer, collected: Collected) -> dict[str, int]:
    snap = observer.snapshot()
    figures: dict[str, int] = {}
    for fmt, arrivals in (("sparkplug", sparkplug_arrivals(snap, "plant", "gw")),
                          ("json", json_arrivals(snap, "focas"))):
        verdict = compare(collected, arrivals)
        assert not verdict.problems(), f"{fmt}: {verdict.problems()}"
        figures[f"{fmt}_historical"] = verdict.historical
        figures[f"{fmt}_duplicates"] = verdict.duplicates
    figures["collected"] = len(collected.keys)
    figures["collected_down"] = sum(1 for p in collected.keys.values() if p == "down")
    return figures


async def test_broker_outage_every_delta_arrives_once_in_order_historical_flagged(
        mosquitto: Mosquitto, relay: TcpRelay, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    daemon, task, collected = await start(config_text(relay.host, relay.port, tmp_path, fleet))
    try:
        await all_born(observer)
        await observer.wait_count("DDATA", 20, timeout=15)
        # The broker dies; the daemon cannot reach it again until the test's subscriber is back.
        collected.phase = "down"
        relay.accepting = False
        observer.expect_reconnect()
        killed = time.monotonic()
        mosquitto.stop(kill=True)
        await async_wait_for(lambda: daemon.spool.pending() > 0, timeout=10, message="spooling")
        await asyncio.sleep(max(0.0, OUTAGE_S - (time.monotonic() - killed)))  # the outage itself
        spooled, reopened = await broker_back(mosquitto, relay, observer, collected, daemon)
        born = time.monotonic()
        await async_wait_for(lambda: daemon.spool.pending() == 0, timeout=60, message="spool replayed")
        replayed = time.monotonic()
        assert all(counts > 0 for k, counts in collected.per_device.items() if k.endswith(":down"))
        assert len([k for k in collected.per_device if k.endswith(":down")]) == MACHINES
        collected.phase = "after"
        await async_wait_for(lambda: collected.per_device.get("m1:after", 0) > 5, timeout=10,
                             message="live data after the replay")
    finally:
        await stop(daemon, task)
    await wait_delivered(observer, collected)
    figures = assert_no_loss(observer, collected)
    # Live data resumed at once: the first live DDATA after the births precedes the end of the replay.
    snap = observer.snapshot()
    nbirths = [i for i, m in enumerate(snap) if m.kind == "NBIRTH"]
    after_birth = snap[nbirths[1]:]
    live = next(i for i, m in enumerate(after_birth)
                if m.kind == "DDATA" and not any(x.is_historical for x in m.spb().metrics))
    last_hist = max(i for i, m in enumerate(after_birth)
                    if m.kind == "DDATA" and any(x.is_historical for x in m.spb().metrics))
    assert live < last_hist, "live data waited for the replay"
    figures.update(outage_s=round(OUTAGE_S), spooled_rows=spooled)
    print(f"\nFIGURES broker outage: {json.dumps(figures)} reconnect_s={born - reopened:.2f} "
          f"replay_s={replayed - born:.2f}")
    assert figures["sparkplug_historical"] > 0 and figures["json_historical"] > 0


async def test_dead_link_is_suspected_before_the_disconnect_and_nothing_is_lost(
        mosquitto: Mosquitto, relay: TcpRelay, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    daemon, task, collected = await start(config_text(relay.host, relay.port, tmp_path, fleet))
    try:
        await all_born(observer)
        await observer.wait_count("DDATA", 20, timeout=15)
        collected.phase = "down"
        relay.blackhole()  # no FIN, no RST: only the missing PUBACK of a probe tells
        await async_wait_for(lambda: daemon.publisher.counters["suspect_dead"] >= 2, timeout=10,
                             message="both connections suspected dead")
        relay.cut()
        collected.phase = "replay"
        await all_born(observer, count=2)
        await async_wait_for(lambda: daemon.spool.pending() == 0, timeout=60, message="spool replayed")
    finally:
        await stop(daemon, task)
    await wait_delivered(observer, collected)
    assert_no_loss(observer, collected)


async def test_primary_host_offline_spools_and_replays_after_online(
        mosquitto: Mosquitto, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    text = config_text(mosquitto.host, mosquitto.port, tmp_path, fleet, ", primary_host_id: scada")
    state = "spBv1.0/STATE/scada"
    t0 = int(time.time() * 1000)
    await observer.publish(state, json.dumps({"online": True, "timestamp": t0}).encode(), retain=True)
    daemon, task, collected = await start(text)
    try:
        await all_born(observer)
        await observer.wait_count("DDATA", 20, timeout=15)
        await observer.publish(state, json.dumps({"online": False, "timestamp": t0 + 1}).encode(), retain=True)
        await async_wait_for(lambda: daemon.publisher.session_state != "born", timeout=10, message="NDEATH")
        collected.phase = "down"  # from here on nothing may go out live
        await async_wait_for(lambda: daemon.spool.pending("sparkplug") > 10, timeout=15,
                             message="spooling while the host is offline")
        assert len(observer.of("NBIRTH")) == 1
        collected.phase = "replay"
        await observer.publish(state, json.dumps({"online": True, "timestamp": t0 + 2}).encode(), retain=True)
        await all_born(observer, count=2)
        await async_wait_for(lambda: daemon.spool.pending("sparkplug") == 0, timeout=60, message="replayed")
    finally:
        await stop(daemon, task)
        await observer.publish(state, b"", retain=True)
    await wait_delivered(observer, collected)
    snap = observer.snapshot()
    verdict = compare(collected, sparkplug_arrivals(snap, "plant", "gw"))
    assert not verdict.problems(), verdict.problems()
    assert verdict.historical > 0


def spooled_keys(path: Path, fmt: str) -> set[tuple[object, ...]]:
    """What a (possibly killed) daemon has in its spool, read by a second SQLite connection."""
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        rows = db.execute("SELECT device, body FROM spool WHERE fmt = ?", (fmt,)).fetchall()
    finally:
        db.close()
    return {key_of(device, s.name, s.timestamp_ms, s.value) for device, body in rows
            for s in decode_samples(bytes(body))}


def spool_rows(path: Path) -> int:
    if not path.exists():
        return 0
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return int(db.execute("SELECT COUNT(*) FROM spool").fetchone()[0])
    except sqlite3.OperationalError:
        return 0
    finally:
        db.close()


async def spawn_daemon(config: Path, log: Path) -> asyncio.subprocess.Process:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])}
    return await asyncio.create_subprocess_exec(sys.executable, "-m", "edge", "run", "--config", str(config),
                                                stdout=asyncio.subprocess.DEVNULL, stderr=log.open("ab"),
                                                env=env)


async def kill_9(proc: asyncio.subprocess.Process) -> None:
    if proc.returncode is None:
        proc.send_signal(signal.SIGKILL)
    await asyncio.wait_for(proc.wait(), 10)


def nbirth_bdseq(observer: Observer) -> list[int]:
    return [next(m.long_value for m in n.spb().metrics if m.name == "bdSeq") for n in observer.of("NBIRTH")]


async def test_kill_9_during_buffering_and_during_replay_loses_nothing_and_state_survives(
        mosquitto: Mosquitto, relay: TcpRelay, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    state_dir = tmp_path / "state"
    config = tmp_path / "edge.yaml"
    config.write_text(config_text(relay.host, relay.port, state_dir, fleet))
    spool = state_dir / "spool.sqlite"
    log = tmp_path / "daemon.log"
    first = await spawn_daemon(config, log)
    try:
        await all_born(observer)
        aliases_before = {d: birth_aliases(observer, d) for d in ("m1", "m2")}
        # Buffering: the daemon cannot reach the broker; kill -9 it with rows in the spool.
        relay.accepting = False
        relay.cut()
        await async_wait_for(lambda: spool_rows(spool) > 150, timeout=30, interval=0.1, message="rows spooled")
        await kill_9(first)
        expected = {fmt: spooled_keys(spool, fmt) for fmt in ("sparkplug", "json")}
        last_bdseq = json.loads((state_dir / "sparkplug_bdseq.json").read_text())["last"]
        relay.accepting = True
        # Replay: kill -9 again once part of the spool has gone out.
        rows = spool_rows(spool)
        second = await spawn_daemon(config, log)
        await observer.wait_count("NBIRTH", 2, timeout=20)
        await async_wait_for(lambda: spool_rows(spool) < rows - 10, timeout=30, interval=0.02,
                             message="replay under way")
        await kill_9(second)
        assert spool_rows(spool) > 0, "the replay finished before the kill: nothing was tested"
        third = await spawn_daemon(config, log)
        await observer.wait_count("NBIRTH", 3, timeout=20)
        await async_wait_for(lambda: spool_rows(spool) == 0, timeout=60, interval=0.1, message="replay done")
        third.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(third.wait(), 20) == 0
    finally:
        for proc in (first, locals().get("second"), locals().get("third")):
            if isinstance(proc, asyncio.subprocess.Process):
                await kill_9(proc)
    snap = observer.snapshot()
    spb = {a.key for a in sparkplug_arrivals(snap, "plant", "gw") if a.historical}
    js = {a.key for a in json_arrivals(snap, "focas") if a.historical}
    assert expected["sparkplug"] and expected["json"]
    assert not expected["sparkplug"] - spb, f"lost {len(expected['sparkplug'] - spb)} Sparkplug samples"
    assert not expected["json"] - js, f"lost {len(expected['json'] - js)} JSON samples"
    # bdSeq continues from the value persisted before the kill; aliases are the same after two crashes.
    bdseqs = nbirth_bdseq(observer)
    assert bdseqs[1] == (last_bdseq + 1) % 256, (last_bdseq, bdseqs)
    assert bdseqs == sorted(bdseqs) or 0 in bdseqs
    for d, aliases in aliases_before.items():
        assert birth_aliases(observer, d) == aliases


async def test_replay_repeats_nothing_a_birth_or_live_data_already_carried(
        mosquitto: Mosquitto, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    """Issue 16.10: after a rebirth and a primary-host offline/online, no historical DDATA repeats a value
    (device, metric, CNC timestamp, value) the host already got live or in a DBIRTH."""
    text = config_text(mosquitto.host, mosquitto.port, tmp_path, fleet, ", primary_host_id: scada")
    state = "spBv1.0/STATE/scada"
    rebirth = Payload(metrics=[Payload.Metric(name=pl.REBIRTH_METRIC, boolean_value=True)]).SerializeToString()
    t0 = int(time.time() * 1000)
    await observer.publish(state, json.dumps({"online": True, "timestamp": t0}).encode(), retain=True)
    daemon, task, collected = await start(text)
    daemon.publisher.settings.rebirth_min_interval_s = 1.0  # the second request waits: data is held
    try:
        await all_born(observer)
        await observer.wait_count("DDATA", 20, timeout=15)
        for count in (2, 3):  # two rebirths, the second held back by the minimum interval
            await observer.publish("spBv1.0/plant/NCMD/gw", rebirth)
            await observer.wait_topic("spBv1.0/plant/NBIRTH/gw", count=count, timeout=15)
        await async_wait_for(lambda: daemon.publisher.counters["replayed_rows"] > 0, timeout=15,
                             message="rows held by the rebirth replayed")
        await observer.publish(state, json.dumps({"online": False, "timestamp": t0 + 1}).encode(), retain=True)
        await async_wait_for(lambda: daemon.publisher.session_state != "born", timeout=10, message="NDEATH")
        await async_wait_for(lambda: daemon.spool.pending("sparkplug") > 10, timeout=15,
                             message="spooling while the host is offline")
        await observer.publish(state, json.dumps({"online": True, "timestamp": t0 + 2}).encode(), retain=True)
        await observer.wait_topic("spBv1.0/plant/NBIRTH/gw", count=4, timeout=15)
        await async_wait_for(lambda: daemon.spool.pending("sparkplug") == 0, timeout=60, message="replayed")
    finally:
        await stop(daemon, task)
        await observer.publish(state, b"", retain=True)
    await wait_delivered(observer, collected)
    arrivals = sparkplug_arrivals(observer.snapshot(), "plant", "gw")
    verdict = compare(collected, arrivals)
    assert not verdict.problems(), verdict.problems()
    assert verdict.historical > 0, "nothing was replayed: the drill tested nothing"
    seen: set[tuple[object, ...]] = set()
    repeated = []  # historical DDATA metrics the host already had (live, in a DBIRTH or replayed before)
    for a in arrivals:
        if a.historical and not a.birth and a.key in seen:
            repeated.append(a.key)
        seen.add(a.key)
    skipped = daemon.publisher.counters["replay_duplicates_skipped"]
    print(f"\nFIGURES replay dedupe: historical={verdict.historical} repeated_by_replay={len(repeated)} "
          f"skipped_at_replay={skipped}")
    assert not repeated, f"{len(repeated)} values the host already had were replayed, e.g. {repeated[:3]}"


async def test_full_disk_broker_outage_reconnects_at_once_bounds_the_spool_and_counts_every_drop(
        mosquitto: Mosquitto, relay: TcpRelay, observer: Observer, fleet: Fleet, tmp_path: Path,
        caplog: pytest.LogCaptureFixture) -> None:
    """Issue 16.6-8: state_dir on a 1 MB tmpfs, the broker away until the disk is full. The node is back as
    soon as the broker is (bdSeq kept in memory), the spool drops the oldest samples and counts them all,
    logs once, and drains what it kept after the births, deleting acknowledged rows on the full disk."""
    caplog.set_level(logging.WARNING)
    with small_disk(tmp_path / "state", "1m") as state:
        daemon, task, collected = await start(config_text(relay.host, relay.port, state, fleet))
        try:
            await all_born(observer)
            await observer.wait_count("DDATA", 20, timeout=15)
            filler = fill(state)  # leave the spool a few hundred kB so the disk is full in seconds
            filler.write_bytes(b"\0" * max(0, filler.stat().st_size - 384 * 1024))
            collected.phase = "down"
            relay.accepting = False
            observer.expect_reconnect()
            mosquitto.stop(kill=True)
            await async_wait_for(lambda: daemon.spool.dropped > 0, timeout=60, message="the disk is full")
            await async_wait_for(lambda: daemon.spool.dropped > 500, timeout=30, message="dropping")
            fill(state, "filler2")  # and nothing at all is left for the bdSeq file
            spooled_rows, reopened = await broker_back(mosquitto, relay, observer, collected, daemon)
            reconnect_s = time.monotonic() - reopened
            await async_wait_for(lambda: daemon.spool.pending() == 0, timeout=60, message="spool drained")
            drained_s = time.monotonic() - reopened
            collected.phase = "after"
            await async_wait_for(lambda: collected.per_device.get("m1:after", 0) > 5, timeout=10,
                                 message="live data after the replay")
        finally:
            deaths = len(observer.of("NDEATH"))
            await stop(daemon, task)
        disk_full_at_connect = daemon.publisher.counters["bdseq_persist_failures"]
    # Dropped samples never arrive, so wait for the last message of each connection instead of for all.
    await observer.wait_count("NDEATH", deaths + 1, timeout=10)
    await async_wait_for(lambda: [m for m in observer.on(f"focas/{GATEWAY}/online") if m.payload == OFFLINE],
                         timeout=10, message="the JSON connection's last message")
    snap = observer.snapshot()
    missing = 0
    figures: dict[str, object] = {}
    for fmt, arrivals in (("sparkplug", sparkplug_arrivals(snap, "plant", "gw")),
                          ("json", json_arrivals(snap, "focas"))):
        verdict = compare(collected, arrivals)
        assert not verdict.unexpected and not verdict.out_of_order, verdict.problems()
        missing += len(verdict.missing)
        figures[f"{fmt}_delivered_historical"] = verdict.historical
        figures[f"{fmt}_missing"] = len(verdict.missing)
    spool = daemon.spool
    figures.update(polled_during_outage=sum(1 for p in collected.keys.values() if p == "down"),
                   spooled_samples=spool.held, dropped_samples=spool.dropped, spooled_rows_at_return=spooled_rows,
                   reconnect_s=round(reconnect_s, 2), drained_s=round(drained_s, 2),
                   bdseq_persist_failures=disk_full_at_connect)
    print(f"\nFIGURES full disk: {json.dumps(figures)}")
    assert disk_full_at_connect >= 1, "the CONNECT after the outage did not meet a full disk"
    assert spool.dropped > 0 and missing <= spool.dropped, "a sample was lost without being counted"
    episodes = [r for r in caplog.records if "spool full, dropping" in r.getMessage()]
    assert len(episodes) == 1, f"one log line per drop episode, got {len(episodes)}"
    failures = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR
                and r.name.startswith("edge.publish")]
    assert not failures, failures[:3]


async def test_rows_waiting_while_connected_are_drained_without_a_reconnect(
        mosquitto: Mosquitto, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    """Issue 16.8: rows left in the spool while the session is up (a replay that ended early, a delete that
    had no room) are replayed within a probe interval, not at the next reconnect."""
    daemon, task, _ = await start(config_text(mosquitto.host, mosquitto.port, tmp_path, fleet))
    try:
        await all_born(observer)
        await async_wait_for(lambda: daemon.publisher.counters["replayed_rows"] == 0 and
                             not daemon.spool.pending(), timeout=10, message="settled")
        connects = daemon.publisher.counters["sparkplug_connects"]
        old = int(time.time() * 1000) - 3_600_000
        for fmt in ("sparkplug", "json"):
            daemon.spool.hold(fmt, "m1", "data", [Sample("Macro/500", 42.5, MetricType.DOUBLE, old)])
        await async_wait_for(lambda: daemon.spool.pending() == 0, timeout=10, message="waiting rows drained")
        assert daemon.publisher.counters["sparkplug_connects"] == connects, "drained by a reconnect"
        await async_wait_for(lambda: [a for a in sparkplug_arrivals(observer.snapshot(), "plant", "gw")
                                      if a.key == ("m1", "Macro/500", old) and a.historical],
                             timeout=10, message="the waiting row arrived as historical")
    finally:
        await stop(daemon, task)
