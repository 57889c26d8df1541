"""`focas-edge watch --config`: where it connects and what it subscribes to."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

from edge.cli.watch import watch_plan
from tests.unit.config.test_gateways import FLEET


def test_watch_takes_the_broker_of_the_gateway_named(tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(textwrap.dedent(FLEET))
    args = argparse.Namespace(config=path, gateway="hall-b", host=None, port=None, group=None, json_prefix=None,
                              no_json=False, no_sparkplug=False)
    plan = watch_plan(args)
    assert (plan.host, plan.port) == ("broker-b", 1884)
    assert "spBv1.0/plant/#" in plan.topics
