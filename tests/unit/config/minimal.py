"""The smallest valid config and the parse helpers the config tests share."""

from __future__ import annotations

import textwrap

import pytest

from edge import ConfigError
from edge.config import Config, parse_config

MINIMAL = """
mqtt:
  host: broker
  sparkplug: {group_id: g, edge_node_id: n}
machines:
  - id: m1
    host: 10.0.0.1
"""


def problems_of(text: str, environ: dict[str, str] | None = None) -> list[str]:
    with pytest.raises(ConfigError) as info:
        parse_config(textwrap.dedent(text), "test.yaml", environ or {})
    return info.value.problems


def parse(text: str, environ: dict[str, str] | None = None) -> Config:
    return parse_config(textwrap.dedent(text), "test.yaml", environ or {})
