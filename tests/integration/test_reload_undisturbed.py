"""A reload that adds one machine to a running fleet leaves every other machine's session alone.

Issue 25 point 4 at a small scale (bench/reload.py measures the same at 1,000 machines): 20 machines
polled by `focas-edge run`, a 21st added to the file and SIGHUP. Only the new machine is born; no other
machine gets a DBIRTH or DDEATH, the node's seq runs on without a gap across the reload, and every old
machine keeps publishing.
"""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.mqtt_observer import Observer, Received
from tests.integration.test_signals import GROUP, DaemonProcess, daemon_config

pytestmark = pytest.mark.integration

MACHINES = 20
POLL = "{periods: {status: 0.2s}}"
NODE_KINDS = ("NBIRTH", "NDATA", "DBIRTH", "DDATA", "DDEATH")  # the messages that carry the node's seq


def seq_breaks(messages: list[Received]) -> list[tuple[str, int, int]]:
    """(topic, expected, got) wherever a node message's seq is not the previous one's + 1 (mod 256)."""
    breaks: list[tuple[str, int, int]] = []
    last: int | None = None
    for message in messages:
        if message.kind not in NODE_KINDS:
            continue
        seq = message.spb().seq
        if message.kind != "NBIRTH" and last is not None and seq != (last + 1) % 256:
            breaks.append((message.topic, (last + 1) % 256, seq))
        last = seq
    return breaks


async def test_a_machine_added_by_reload_is_born_alone_and_the_node_seq_runs_on(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i") for _ in range(MACHINES + 1)], base_port=0) as fleet:
        ports = {f"m{i + 1:02d}": machine.port for i, machine in enumerate(fleet)}
        old = dict(list(ports.items())[:MACHINES])
        polls = dict.fromkeys(ports, POLL)
        config, state = tmp_path / "edge.yaml", tmp_path / "state"
        config.write_text(daemon_config(mosquitto, state, old, polls))
        daemon = DaemonProcess(config)
        await daemon.start()
        try:
            await async_wait_for(lambda: len(observer.of("DBIRTH")) >= MACHINES, 60, message="20 DBIRTHs")
            await async_wait_for(lambda: all(observer.on(f"{GROUP}/DDATA/gw/{m}") for m in old), 30,
                                 message="DDATA from every machine")
            before = len(observer.snapshot())

            config.write_text(daemon_config(mosquitto, state, ports, polls))
            daemon.signal(signal.SIGHUP)
            await observer.wait_topic(f"{GROUP}/DBIRTH/gw/m21", timeout=20)
            after_reload = len(observer.snapshot())

            def all_published_since() -> bool:
                since = observer.snapshot()[after_reload:]
                return {m.topic for m in since if m.kind == "DDATA"} >= {f"{GROUP}/DDATA/gw/{m}" for m in ports}
            await async_wait_for(all_published_since, 20, message="DDATA from all 21 machines after the reload")
            daemon.signal(signal.SIGTERM)
            assert await daemon.wait(15) == 0, daemon.output()
        finally:
            await daemon.kill()
    messages = observer.snapshot()
    assert "reloaded added=['m21'] removed=[] changed=[]" in daemon.output()
    during = [m for m in messages[before:] if m.kind in ("NBIRTH", "DBIRTH", "DDEATH")]
    born_or_dead = [(m.kind, m.topic.rsplit("/", 1)[-1]) for m in during]
    # Up to the daemon's stop (its DDEATHs, NDEATH) only m21's birth may appear.
    stopped_at = next((i for i, (kind, _) in enumerate(born_or_dead) if kind == "DDEATH"), len(born_or_dead))
    assert born_or_dead[:stopped_at] == [("DBIRTH", "m21")], born_or_dead[:stopped_at]
    assert len(observer.of("NBIRTH")) == 1, "the broker session was kept"
    assert seq_breaks(messages) == [], "the node's seq runs on across the reload"
