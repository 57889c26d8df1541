"""The daemon config the integration tests share: the suite's broker, both formats, group `plant`, node `gw`."""

from __future__ import annotations

from pathlib import Path

from tests.helpers import Mosquitto


def daemon_config(broker: Mosquitto, state_dir: Path, machines: str, extra: str = "") -> str:
    """Config text; `machines` are YAML list entries, `extra` more top-level sections (alarms, writes ...)."""
    return f"""
mqtt:
  host: {broker.host}
  port: {broker.port}
  formats: [sparkplug, json]
  sparkplug: {{group_id: plant, edge_node_id: gw}}
  json: {{prefix: focas}}
state_dir: {state_dir}
{extra}
machines:
{machines}
"""
