"""`focas-edge watch --config FILE` watches what that daemon publishes: its broker, group and JSON prefix."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from edge.publish.sparkplug_b_pb2 import Payload
from tests.helpers import Mosquitto, wait_for

pytestmark = pytest.mark.integration


class Lines:
    """The output of a running `watch`, collected by a reader thread."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def has(self, text: str) -> bool:
        return any(text in line for line in list(self.lines))


@pytest.fixture
def watch_config(mosquitto: Mosquitto, tmp_path: Path) -> Iterator[Lines]:
    config = tmp_path / "edge.yaml"
    config.write_text(f"""
mqtt:
  host: {mosquitto.host}
  port: {mosquitto.port}
  sparkplug: {{group_id: line7, edge_node_id: gw}}
  json: {{prefix: site/cells}}
state_dir: {tmp_path / 'state'}
machines:
  - {{id: m1, host: 127.0.0.1}}
""")
    proc = subprocess.Popen([sys.executable, "-m", "edge", "watch", "--config", str(config)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        yield Lines(proc)
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def publish(broker: Mosquitto, messages: list[tuple[str, bytes]], retain: bool) -> None:
    client = paho.Client(CallbackAPIVersion.VERSION2)
    client.connect(broker.host, broker.port)
    client.loop_start()
    for topic, payload in messages:
        client.publish(topic, payload, qos=1, retain=retain).wait_for_publish(5)
    client.disconnect()
    client.loop_stop()


def test_watch_takes_broker_group_and_prefix_from_the_config(mosquitto: Mosquitto, watch_config: Lines) -> None:
    death = Payload(timestamp=1, seq=4).SerializeToString()
    value = json.dumps({"value": 7, "quality": "GOOD"}).encode()
    publish(mosquitto, [("spBv1.0/other/DDEATH/gw/x9", death), ("focas/x9/state/Parts", value),
                        ("spBv1.0/line7/DDEATH/gw/m1", death), ("site/cells/m1/state/Parts", value)], retain=True)
    wait_for(lambda: watch_config.has("DDEATH gw/m1 seq=4") and watch_config.has("site/cells/m1/state/Parts = 7"),
             20, message="the config's group and prefix seen")
    # Anything retained elsewhere arrived with the subscriptions; a later message proves they were all handled.
    publish(mosquitto, [("site/cells/m1/state/Done", value)], retain=False)
    wait_for(lambda: watch_config.has("site/cells/m1/state/Done"), 20, message="the later message")
    assert not watch_config.has("x9"), watch_config.lines
    assert watch_config.has(f"watching {mosquitto.host}:{mosquitto.port}")


def test_a_bad_config_is_a_usage_error_naming_the_problem(tmp_path: Path) -> None:
    config = tmp_path / "edge.yaml"
    config.write_text("mqtt: {host: h, sparkplug: {group_id: a/b, edge_node_id: gw}}\nmachines: [{id: m1}]\n")
    done = subprocess.run([sys.executable, "-m", "edge", "watch", "--config", str(config)],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2
    assert "mqtt.sparkplug.group_id" in done.stderr
    assert "machines[0].host: required" in done.stderr
