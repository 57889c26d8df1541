"""After a broker outage the daemon is back within about a second of the broker, not a backoff later.

simulator -> daemon -> relay -> real mosquitto -> subscriber. The broker is killed and started again on its
port; the relay's port (the daemon's broker address) refuses connects until the test's subscriber is back,
as a broker that is down does, so the subscriber sees every message of the daemon's return. The outage lasts
until the daemon has failed enough attempts for the old backoff (doubling to `reconnect_max_s`, 30 s here)
to be at 15-30 s: the data must resume well inside that. How fast it resumes is the benchmark's
(`python -m bench outage`); here only that it is not a backoff late, and in Sparkplug's order.

The same for a broker address that accepts the TCP connect and closes it before CONNACK (a proxy or load
balancer in front of a broker that is down, the soak's relay): the delay is capped at
`reconnect_not_serving_s` while it lasts, not at the backoff's `reconnect_max_s`, and never under half of it.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.publish.forwarding import ForwardingPolicy
from edge.publish.mqtt import MqttConnection
from edge.publish.settings import PublishSettings
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.delivery import changing_fleet
from tests.integration.mqtt_observer import Observer, Received
from tests.integration.tcp_relay import TcpRelay

pytestmark = pytest.mark.integration

MACHINES = 2
BACKOFF_MAX_S = 30.0
FAILED_ATTEMPTS = 7  # the old backoff after these: 0.5 s * 2**7 capped at 30 s, drawn in [15, 30] s
RESUMED_WITHIN_S = 10.0  # under the old backoff's least delay (15 s): a probe (<= 1 s) plus the births


@pytest.fixture
async def fleet() -> AsyncIterator[Fleet]:
    async with changing_fleet(MACHINES) as f:
        yield f

def config_text(relay: TcpRelay, state_dir: Path, fleet: Fleet) -> str:
    machines = "".join(
        f"  - {{id: m{i + 1}, host: 127.0.0.1, port: {m.port}, "
        f"poll: {{periods: {{status: 0.2s, macros: 0.2s}}, macros: [500]}}}}\n" for i, m in enumerate(fleet))
    return (f"mqtt:\n  host: {relay.host}\n  port: {relay.port}\n  keepalive: 5\n  formats: [sparkplug]\n"
            f"  sparkplug: {{group_id: plant, edge_node_id: gw}}\nstate_dir: {state_dir}\nmachines:\n{machines}")


def historical(m: Received) -> bool:
    return any(x.is_historical for x in m.spb().metrics)


async def test_data_resumes_promptly_after_an_outage_births_first_then_the_backlog(
        mosquitto: Mosquitto, relay: TcpRelay, observer: Observer, fleet: Fleet, tmp_path: Path) -> None:
    daemon = Daemon(parse_config(config_text(relay, tmp_path, fleet)))
    daemon.publisher.forwarding = ForwardingPolicy(probe_interval_s=0.3, probe_timeout_s=1.5)
    daemon.publisher.settings.reconnect_min_s = 0.5
    daemon.publisher.settings.reconnect_max_s = BACKOFF_MAX_S
    task = asyncio.create_task(daemon.run())
    try:
        for i in range(MACHINES):
            await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/m{i + 1}", timeout=20)
        await observer.wait_count("DDATA", 10, timeout=15)
        await relay.stop_listening()
        observer.expect_reconnect()
        mosquitto.stop(kill=True)

        def failed_attempts() -> int:
            (_, state), = daemon.publisher.broker_states()
            return state.failed_attempts

        await async_wait_for(lambda: failed_attempts() >= FAILED_ATTEMPTS and daemon.spool.pending() > 0,
                             timeout=60, message=f"{FAILED_ATTEMPTS} failed attempts and rows spooled")
        mosquitto.start()
        await observer.wait_resubscribed()
        mark = len(observer.snapshot())
        await relay.start()  # the broker's address answers again

        def live_data_from_every_machine() -> bool:
            after = observer.snapshot()[mark:]
            return all(any(m.topic == f"spBv1.0/plant/DDATA/gw/m{i + 1}" and not historical(m) for m in after)
                       for i in range(MACHINES))

        await async_wait_for(live_data_from_every_machine, timeout=RESUMED_WITHIN_S, interval=0.05,
                             message="live data from every machine after the broker's return")
        await async_wait_for(lambda: daemon.spool.pending() == 0, timeout=30, message="the backlog replayed")
    finally:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 20) == 0
    after = [m for m in observer.snapshot()[mark:] if m.topic.startswith("spBv1.0/plant/")]
    assert after[0].kind == "NBIRTH", [m.topic for m in after[:3]]
    for i in range(MACHINES):
        device = [m for m in after if m.topic.endswith(f"/gw/m{i + 1}")]
        assert device[0].kind == "DBIRTH", [m.topic for m in device[:3]]
        assert any(m.kind == "DDATA" and historical(m) for m in device), f"m{i + 1}: no backlog replayed"


async def test_a_broker_that_accepts_and_closes_is_retried_at_most_once_a_second_and_reached_within_the_cap(
        relay: TcpRelay) -> None:
    settings = PublishSettings(host=relay.host, port=relay.port, keepalive=5, reconnect_min_s=0.5,
                               reconnect_max_s=BACKOFF_MAX_S, reconnect_not_serving_s=2.0)
    cap = settings.reconnect_not_serving_s
    relay.accepting = False  # the TCP connect succeeds, then the relay closes it before any CONNACK
    conn = MqttConnection(settings, "not-serving", before_connect=lambda unsent: None,
                          on_connected=lambda tag: None, on_disconnected=lambda: None, on_message=lambda msg: None)
    loop = asyncio.get_running_loop()
    started = loop.time()
    conn.start()
    try:
        # The old backoff after these: 0.5 s * 2**6 capped at 30 s, drawn in [15, 30] s.
        await async_wait_for(lambda: conn.trouble.failed_attempts >= FAILED_ATTEMPTS - 1,
                             timeout=(FAILED_ATTEMPTS - 1) * cap + 10,
                             message=f"{FAILED_ATTEMPTS - 1} attempts turned away")
        assert not conn.connected
        # Not hammered: each retry waited at least half the cap (1 s here).
        assert loop.time() - started >= (FAILED_ATTEMPTS - 2) * cap / 2 - 0.05
        reopened = loop.time()
        relay.accepting = True
        await async_wait_for(lambda: conn.connected, timeout=cap + 1.0, interval=0.02,
                             message=f"the CONNACK within {cap} s (+1 s) of the broker serving again")
        assert loop.time() - reopened <= cap + 1.0
        assert relay.accepted == 1
    finally:
        await conn.stop()
