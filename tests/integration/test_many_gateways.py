"""Many gateways from one fleet file, on two mosquitto brokers bridged to each other (docs/install.md, "Many
gateways"): two `focas-edge run --gateway` processes, simulated CNCs over TCP, a subscriber on each broker.

Every machine is seen exactly once on either broker (one DBIRTH, its data from one edge node id, no message
twice), the two edge nodes never collide (one NBIRTH each, no NDEATH while running), and moving a machine
between gateways (edit the file, SIGHUP the gaining gateway, then the losing one) loses no sample: each
node's Sparkplug seq runs without a hole on both brokers, the gaining gateway's first read of the moved
machine is older (by the CNC's clock) than the losing one's last, and its CNC-clock macro, polled every 100 ms, has
no hole across the move longer than those of the machines that stayed.
"""

from __future__ import annotations

import itertools
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge.sim.fleet import Fleet, MachineSpec
from edge.sim.state_clock import CLOCK_MACRO_MODULO
from tests.helpers import Mosquitto, async_wait_for, mosquitto_binary
from tests.integration.delivery import sparkplug_arrivals
from tests.integration.mqtt_observer import Observer, Received
from tests.integration.test_signals import DaemonProcess, daemons  # noqa: F401 (daemons: the fixture)

pytestmark = pytest.mark.integration

GROUP = "spBv1.0/plant"
CLOCK_MACRO = 500
PERIOD_S = 0.1
MOVED = "m1"
HALLS = {"hall-a": ("m1", "m2"), "hall-b": ("m3", "m4")}
# Polls 100 ms apart, each stamped with CNC time: a hole in the moved machine's series longer than this (or
# than the worst hole of a machine that did not move, on a loaded host) is a stretch nobody polled it. The
# test's bound, not a speed target: several periods of scheduling slack.
MAX_GAP_MS = 600
STAYED = {"hall-a": "m2", "hall-b": "m3"}


@pytest.fixture
def bridged() -> Iterator[tuple[Mosquitto, Mosquitto]]:
    """Broker A and broker B, A bridged to B both ways (one bridge: mosquitto's no-local keeps it loop-free)."""
    binary = mosquitto_binary()
    if binary is None:
        pytest.skip("mosquitto is not installed (make test installs it where it can)")
    a, b = Mosquitto(binary), Mosquitto(binary)
    with a.conf.open("a") as conf:
        conf.write(f"connection hall-bridge\naddress {b.host}:{b.port}\n"
                   "topic spBv1.0/# both 1\ntopic probe/# both 1\ncleansession true\nrestart_timeout 1\n")
    try:
        b.start()
        a.start()
        yield a, b
    finally:
        a.close()
        b.close()


def fleet_file(brokers: tuple[Mosquitto, Mosquitto], state: Path, ports: dict[str, int],
               owners: dict[str, str]) -> str:
    """One file for both gateways: hall-a on broker A, hall-b on broker B, edge node ids from their names."""
    a, b = brokers
    machines = "".join(f"  - {{id: {mid}, gateway: {owners[mid]}, port: {port}}}\n" for mid, port in ports.items())
    return f"""
defaults:
  host: 127.0.0.1
  poll: {{periods: {{status: 1s, macros: {PERIOD_S}s}}, macros: [{CLOCK_MACRO}]}}
  timeouts: {{request_s: 1, connect_s: 1, backoff_initial_s: 0.1, backoff_max_s: 0.3}}
mqtt:
  formats: [sparkplug]
  sparkplug: {{group_id: plant}}
gateways:
  hall-a:
    mqtt: {{host: {a.host}, port: {a.port}}}
    state_dir: {state / "hall-a"}
  hall-b:
    mqtt: {{host: {b.host}, port: {b.port}}}
    state_dir: {state / "hall-b"}
machines:
{machines}"""


def seq_holes(messages: list[Received], node: str) -> list[str]:
    """Places where a node's Sparkplug seq (NBIRTH 0, then +1 mod 256 per message) skips or repeats."""
    holes = []
    previous: int | None = None
    for m in messages:
        parts = m.topic.split("/")
        if len(parts) < 4 or parts[3] != node or m.kind == "NDEATH":
            continue
        seq = m.spb().seq
        if previous is not None and m.kind != "NBIRTH" and seq != (previous + 1) % 256:
            holes.append(f"{m.topic}: seq {seq} after {previous}")
        previous = seq
    return holes


def clock_reads(messages: list[Received], node: str, device: str) -> list[int]:
    """The CNC clock (ms, unwrapped) at every read of the clock macro that `node` published for `device`: one
    per poll, from the CNC itself, so comparable across gateways (a sample's timestamp is each gateway's own
    estimate of CNC time, coarse for a machine it has just connected)."""
    names: dict[int, str] = {}
    reads: list[int] = []
    for m in messages:
        if m.topic not in (f"{GROUP}/DBIRTH/{node}/{device}", f"{GROUP}/DDATA/{node}/{device}"):
            continue
        payload = m.spb()
        if m.kind == "DBIRTH":
            names = {metric.alias: metric.name for metric in payload.metrics}
        for metric in payload.metrics:
            if (metric.name or names.get(metric.alias)) == f"Macro/{CLOCK_MACRO}" and not metric.is_null:
                reads.append(round(getattr(metric, metric.WhichOneof("value") or "double_value") * 1000))
    return reads


def unwrapped(reads: list[int], reference_ms: int) -> list[int]:
    """The clock macro counts seconds modulo 1000 (clock_macro_value): undo a wrap since `reference_ms`."""
    return [reference_ms + round(read - reference_ms) % round(CLOCK_MACRO_MODULO * 1000) for read in reads]


async def wait_both(observers: list[Observer], topic: str, timeout: float = 20) -> None:
    for observer in observers:
        await observer.wait_topic(topic, timeout=timeout)


async def bridge_up(a: Mosquitto, b: Mosquitto) -> list[Observer]:
    """A subscriber on each broker, once a probe published on either has reached the other through the bridge."""
    observers = [Observer(a, ("spBv1.0/#", "probe/#")), Observer(b, ("spBv1.0/#", "probe/#"))]

    async def crossed(sender: Observer, receiver: Observer, topic: str) -> bool:
        if receiver.on(topic):
            return True
        await sender.publish(topic, b"x")  # again until one gets through: the bridge may not be up yet
        return False

    for sender, receiver, topic in ((observers[0], observers[1], "probe/a"), (observers[1], observers[0], "probe/b")):
        await async_wait_for(lambda s=sender, r=receiver, t=topic: crossed(s, r, t), 20, interval=0.1,
                             message=f"{topic} across the bridge")
    return observers


async def test_two_gateways_share_one_fleet_file_and_a_machine_moves_without_losing_a_sample(
        bridged: tuple[Mosquitto, Mosquitto], daemons: list[DaemonProcess], tmp_path: Path) -> None:  # noqa: F811
    a, b = bridged
    observers = await bridge_up(a, b)
    try:
        specs = [MachineSpec(profile="30i", clock_macro=CLOCK_MACRO) for _ in range(4)]
        async with Fleet(specs, base_port=0) as fleet:
            ports = {f"m{i + 1}": sim.port for i, sim in enumerate(fleet)}
            owners = {mid: hall for hall, mids in HALLS.items() for mid in mids}
            path = tmp_path / "fleet.yaml"
            path.write_text(fleet_file(bridged, tmp_path / "state", ports, owners))
            gateways = {hall: DaemonProcess(path, env={"FOCAS_EDGE_GATEWAY": hall}) for hall in HALLS}
            for hall, daemon in gateways.items():
                daemon.log = tmp_path / f"{hall}.log"  # one file, two processes: a log each
            daemons.extend(gateways.values())
            for daemon in gateways.values():
                await daemon.start()
            try:
                for hall, mids in HALLS.items():
                    for mid in mids:
                        await wait_both(observers, f"{GROUP}/DBIRTH/{hall}/{mid}")
            except AssertionError as exc:  # say what each gateway was doing
                logs = "\n".join(f"--- {hall}:\n{daemon.output()[-3000:]}" for hall, daemon in gateways.items())
                raise AssertionError(f"{exc}\n{logs}") from None
            await async_wait_for(lambda: all(len(clock_reads(o.snapshot(), "hall-a", MOVED)) >= 10
                                             for o in observers), 20, message="the moved machine's data")

            # The move: m1 to hall-b. The gaining gateway first; once it publishes m1's data, the losing one.
            path.write_text(fleet_file(bridged, tmp_path / "state", ports, {**owners, MOVED: "hall-b"}))
            gateways["hall-b"].signal(signal.SIGHUP)
            await wait_both(observers, f"{GROUP}/DBIRTH/hall-b/{MOVED}")
            await async_wait_for(lambda: all(len(clock_reads(o.snapshot(), "hall-b", MOVED)) >= 5 for o in observers),
                                 20, message="hall-b publishing the moved machine's data")
            gateways["hall-a"].signal(signal.SIGHUP)
            await wait_both(observers, f"{GROUP}/DDEATH/hall-a/{MOVED}")
            await async_wait_for(lambda: all(len(clock_reads(o.snapshot(), "hall-b", MOVED)) >= 20
                                             for o in observers), 20, message="m1 from hall-b after the move")
            for daemon in gateways.values():
                daemon.signal(signal.SIGTERM)
            for daemon in gateways.values():
                assert await daemon.wait(15) == 0, daemon.output()
            for hall in HALLS:
                await wait_both(observers, f"{GROUP}/NDEATH/{hall}", timeout=10)
        assert "reload: machine m1 moved to gateway hall-b" in gateways["hall-a"].output()
        assert "reloaded added=['m1'] removed=[] changed=[]" in gateways["hall-b"].output()

        for side, observer in zip("AB", observers, strict=True):
            messages = observer.snapshot()
            spb = [m for m in messages if m.kind]
            births = sorted((m.topic.split("/")[3], m.topic.split("/")[-1]) for m in spb if m.kind == "DBIRTH")
            assert births == sorted([("hall-a", "m1"), ("hall-a", "m2"), ("hall-b", "m1"), ("hall-b", "m3"),
                                     ("hall-b", "m4")]), f"broker {side}: each machine born once per node: {births}"
            assert sorted(m.topic for m in spb if m.kind == "NBIRTH") == [f"{GROUP}/NBIRTH/hall-a",
                                                                         f"{GROUP}/NBIRTH/hall-b"], side
            assert sorted(m.topic for m in spb if m.kind == "NDEATH") == [f"{GROUP}/NDEATH/hall-a",
                                                                         f"{GROUP}/NDEATH/hall-b"], side
            data_from = {(m.topic.split("/")[3], m.topic.split("/")[-1]) for m in spb if m.kind == "DDATA"}
            assert data_from <= {("hall-a", "m1"), ("hall-a", "m2"), ("hall-b", "m1"), ("hall-b", "m3"),
                                 ("hall-b", "m4")}, f"broker {side}: a machine's data from another node: {data_from}"
            for node in HALLS:
                assert seq_holes(spb, node) == [], f"broker {side}, node {node}: messages lost or doubled"
                keys = [a.key for a in sparkplug_arrivals(spb, "plant", node) if not a.birth]
                assert len(keys) == len(set(keys)), f"broker {side}: a sample of {node} arrived twice"
            # hall-a sent nothing of m1 after its DDEATH; hall-b nothing before its DBIRTH.
            kinds = [(m.kind, m.topic.split("/")[3]) for m in spb if m.topic.endswith(f"/{MOVED}")]
            death = kinds.index(("DDEATH", "hall-a"))
            assert ("DDATA", "hall-a") not in kinds[death:], side
            assert ("DDATA", "hall-b") not in kinds[:kinds.index(("DBIRTH", "hall-b"))], side
            first = clock_reads(spb, "hall-a", MOVED)[0]
            losing, gaining = (unwrapped(clock_reads(spb, node, MOVED), first) for node in HALLS)
            assert min(gaining) < max(losing), (f"broker {side}: no overlap: hall-b's first read of {MOVED} "
                                                f"(CNC clock {min(gaining)}) after hall-a's last ({max(losing)})")
            reads = sorted(set(losing) | set(gaining))
            moved_at = min(gaining)
            worst = max((later - earlier, earlier) for earlier, later in itertools.pairwise(reads))
            jitter = max(later - earlier for node, device in STAYED.items()
                         for reads in [clock_reads(spb, node, device)]
                         for earlier, later in itertools.pairwise(sorted(unwrapped(reads, reads[0]))))
            bound = max(MAX_GAP_MS, jitter + 3 * PERIOD_S * 1000)
            assert worst[0] <= bound, (f"broker {side}: {MOVED} unpolled for {worst[0]} ms from CNC clock {worst[1]} "
                                       f"(the move began at {moved_at}; machines that stayed: {jitter} ms at worst)")
            assert reads[0] < moved_at < reads[-1]
    finally:
        for observer in observers:
            observer.close()
