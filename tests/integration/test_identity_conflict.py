"""Two gateways with one Sparkplug identity on one broker (a cloned config, separate state_dirs): each says so
in one ERROR naming the id and what it saw, backs off instead of flapping, and counts it in
focas_edge_identity_conflicts_total and status.json. Real mosquitto, real `focas-edge run` subprocesses.

Both paths: the client id derived from the ids (the broker hands the session to whichever connected last; the
suite's mosquitto 2.0 just closes the old one, with MQTT 5 too, so no reason code helps), and distinct client
ids (each sees the other's NBIRTH).
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import pytest

from edge.publish import Publisher, PublishSettings
from edge.sim.fleet import Fleet, MachineSpec
from tests.helpers import Mosquitto, async_wait_for, free_port, port_open
from tests.integration.mqtt_observer import Observer
from tests.integration.test_signals import DaemonProcess
from tests.integration.test_status_http import http_get, samples
from tests.integration.test_status_page import chromium, run_browser

pytestmark = pytest.mark.integration

NBIRTH = "spBv1.0/plant/NBIRTH/gw"
WINDOW_S = 25.0  # today's flapping: ~2.6 NBIRTH a second, so ~65 in this window
MOST_NBIRTHS = 10  # a few before the verdict (3 short sessions each), then one a minute at most


def config(broker: Mosquitto, state_dir: Path, port: int, protocol: str, extra: str = "") -> str:
    return f"""
mqtt:
  host: {broker.host}
  port: {broker.port}
  protocol: "{protocol}"
  formats: [sparkplug, json]
  sparkplug: {{group_id: plant, edge_node_id: gw}}
{extra}
state_dir: {state_dir}
machines:
  - {{id: m1, host: 127.0.0.1, port: {port}}}
"""


def errors(daemon: DaemonProcess) -> list[str]:
    return [line for line in daemon.output().splitlines() if "identity conflict:" in line and "ERROR" in line]


async def start_pair(tmp_path: Path, texts: tuple[str, str], http_ports: tuple[int, int]) -> list[DaemonProcess]:
    daemons = []
    for name, text, http_port in zip(("first", "second"), texts, http_ports, strict=True):
        path = tmp_path / f"{name}.yaml"
        path.write_text(text + f"http: {{enabled: true, host: 127.0.0.1, port: {http_port}}}\n")
        daemon = DaemonProcess(path)
        daemons.append(daemon)
        await daemon.start()
    return daemons


async def wait_for_conflict(daemons: list[DaemonProcess]) -> None:
    """Until one of them logs the ERROR; on a timeout the failure carries both logs' tails."""
    try:
        await async_wait_for(lambda: any(errors(d) for d in daemons), 30, message="an identity conflict ERROR")
    except AssertionError as exc:
        tails = "\n".join(f"--- {d.config.name}\n" + "\n".join(d.output().splitlines()[-25:]) for d in daemons)
        raise AssertionError(f"{exc}\n{tails}") from None


async def test_a_taken_over_client_id_is_one_error_and_a_backoff_not_a_birth_storm(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    observer = Observer(mosquitto, topics=(NBIRTH,))
    http_ports = (free_port(), free_port())
    daemons: list[DaemonProcess] = []
    try:
        async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
            texts = tuple(config(mosquitto, tmp_path / name, fleet[0].port, "3.1.1") for name in ("a", "b"))
            daemons = await start_pair(tmp_path, (texts[0], texts[1]), http_ports)
            # The gateway whose session is taken first says so at once and backs off; the other sees its
            # session end once a minute and says so within hold_s (edge.publish.identity).
            await wait_for_conflict(daemons)
            index = next(i for i, d in enumerate(daemons) if errors(d))
            http_port = http_ports[index]

            # While the conflict lasts, both back off: the window passes without a birth storm.
            with pytest.raises(AssertionError):
                await async_wait_for(lambda: len(observer.on(NBIRTH)) > MOST_NBIRTHS, WINDOW_S,
                                     message="a birth storm")
            assert len(observer.on(NBIRTH)) <= MOST_NBIRTHS
            (line,) = errors(daemons[index])  # one ERROR, not one per reconnect
            assert "Sparkplug id plant/gw" in line and "client id focas-edge-plant-gw" in line, line

            await async_wait_for(lambda: port_open("127.0.0.1", http_port), 10, message="status endpoint")
            _, _, body = await http_get(http_port, "/metrics")
            assert samples(body.decode())[("focas_edge_identity_conflicts_total", ())] >= 1
            _, _, body = await http_get(http_port, "/status.json")
            conflict = json.loads(body)["gateway"]["identity_conflict"]
            assert conflict["identity"] == "Sparkplug id plant/gw" and conflict["count"] >= 1, conflict
            _, _, page = await http_get(http_port, "/")
            assert b"CONFLICT since" in page
            binary = chromium()
            if binary is not None:  # the page's script redraws the line from status.json without failing
                dom = await run_browser(binary, f"http://127.0.0.1:{http_port}/", "--dump-dom")
                updates = re.search(r'data-updates="(\d+)"', dom)
                assert updates and int(updates.group(1)) >= 2, dom[:2000]
                line = r'<dd id="identity-conflict" class="down">CONFLICT since [^<]*Sparkplug id plant/gw'
                assert re.search(line, dom), dom[:2000]
    finally:
        for daemon in daemons:
            await daemon.kill()
        observer.close()


async def test_another_sessions_nbirth_for_our_id_is_an_identity_conflict(
        mosquitto: Mosquitto, tmp_path: Path) -> None:
    """Distinct client ids: no session is taken over, but one gateway sees the other's NBIRTH on its id."""
    daemons: list[DaemonProcess] = []
    try:
        async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
            texts = tuple(config(mosquitto, tmp_path / name, fleet[0].port, "3.1.1", f"  client_id: gw-{name}")
                          for name in ("a", "b"))
            daemons = await start_pair(tmp_path, (texts[0], texts[1]), (free_port(), free_port()))
            await wait_for_conflict(daemons)
            line = next(line for d in daemons for line in errors(d))
            assert "Sparkplug id plant/gw" in line and "an NBIRTH for this id from another session" in line, line
    finally:
        for daemon in daemons:
            await daemon.kill()


async def test_a_restarting_broker_is_not_taken_for_a_clone(mosquitto: Mosquitto, tmp_path: Path,
                                                             caplog: pytest.LogCaptureFixture) -> None:
    """Three short sessions in a row, but each time the broker was away before it took the gateway back."""
    caplog.set_level(logging.INFO)
    settings = PublishSettings(host=mosquitto.host, port=mosquitto.port, state_dir=tmp_path, group_id="plant",
                               edge_node_id="gw", client_id="focas-edge-plant-gw", reconnect_max_s=0.5)
    publisher = Publisher(settings)
    await publisher.start()
    try:
        assert await publisher.wait_ready(10)
        def refused() -> int:
            return sum("connect failed" in r.getMessage() for r in caplog.records)

        for restart in range(4):
            target = refused() + 2
            mosquitto.stop()
            await async_wait_for(lambda: refused() >= target, 10,  # noqa: B023 (awaited in this iteration)
                                 message="both connections refused while it is away")
            mosquitto.start()
            assert await publisher.wait_ready(15), f"back after restart {restart + 1}"
        assert publisher.identity.count == 0 and publisher.identity.conflict is None
        assert not [r for r in caplog.records if "identity conflict" in r.getMessage()]
    finally:
        await publisher.stop()
