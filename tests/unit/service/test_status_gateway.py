"""The gateway block of the status page and systemd's STATUS= line: which gateway, and its broker session."""

from __future__ import annotations

import html
from types import SimpleNamespace
from typing import Any

from edge import __version__
from edge.publish.broker_trouble import BrokerState
from edge.service.status_gateway import (
    broker_document,
    broker_text,
    gateway_identity,
    render_gateway_block,
    systemd_status,
    uptime_text,
)
from edge.service.value_freshness import local_iso

T0 = 1_800_000_000.0


def daemon(*states: tuple[str, BrokerState], online: tuple[bool, ...] = (True, False)) -> Any:
    publisher = SimpleNamespace(settings=SimpleNamespace(group_id="plant", edge_node_id="gw1"),
                                broker_states=lambda: list(states))
    pollers = {f"m{i}": SimpleNamespace(online=up) for i, up in enumerate(online)}
    return SimpleNamespace(publisher=publisher, pollers=pollers, uptime_s=93_784.0, config_path="/etc/focas-edge.yaml")


def state(connected: bool, since: float, error: str = "") -> BrokerState:
    return BrokerState("10.0.0.5:1883", "gw1", connected, since, error, "refused" if error else "", 3 if error else 0)


def test_the_identity_names_node_version_host_uptime_and_config_file() -> None:
    identity = gateway_identity(daemon(), T0)
    assert identity["edge_node_id"] == "plant/gw1" and identity["version"] == __version__
    assert identity["host_name"] and identity["config_file"] == "/etc/focas-edge.yaml"
    assert identity["uptime_s"] == 93_784 and identity["started_at"] == local_iso(T0 - 93_784)
    assert identity["local_time"] == local_iso(T0)
    assert uptime_text(93_784) == "1d 02:03:04" and uptime_text(59) == "00:00:59"


def test_a_broker_down_on_one_connection_is_down_since_then_with_its_error() -> None:
    broker = broker_document(daemon(("sparkplug", state(True, T0 - 100)),
                                    ("json", state(False, T0 - 40, "connect failed: [Errno 111] Connection refused"))))
    assert not broker["connected"] and broker["connected_since"] is None
    assert broker["down_since"] == local_iso(T0 - 40) and broker["address"] == "10.0.0.5:1883"
    assert "Connection refused" in broker["last_error"]
    assert [c["format"] for c in broker["connections"]] == ["sparkplug", "json"]
    assert broker_text(broker) == (f"broker 10.0.0.5:1883 DOWN since {local_iso(T0 - 40)}: "
                                   "connect failed: [Errno 111] Connection refused")


def test_systemd_status_says_machines_and_broker_in_one_line() -> None:
    up = daemon(("sparkplug", state(True, T0 - 100)), ("json", state(True, T0 - 90)))
    assert systemd_status(up) == ("1 of 2 machine(s) connected; broker 10.0.0.5:1883 connected since "
                                  f"{local_iso(T0 - 90)}")


def test_the_block_escapes_what_it_shows() -> None:
    d = daemon(("json", state(False, T0, "<refused>")))
    block = render_gateway_block(gateway_identity(d, T0), broker_document(d))
    assert '<dd id="gw-edge_node_id">plant/gw1</dd>' in block and "<refused>" not in block
    assert html.escape("<refused>") in block and 'id="broker-detail" class="down"' in block
