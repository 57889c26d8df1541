"""Write latency: a JSON command on `<prefix>/<machine>/cmd` -> CNC write -> `<prefix>/<machine>/cmd/reply`.

One simulated CNC (native and packed surfaces) in its own process, the daemon in its own process with
writes enabled for macros 500-599, and this process as the MQTT client that sends one command at a time
and waits for its reply. Reported per transport: p50/p99 of publish-to-reply time, and whether the
replies said ok. If the command layer answers "not_supported" (not built yet) the result is "pending".
"""

from __future__ import annotations

import json
import shutil
import socket
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from bench.procs import DaemonProcess, SimProcess
from bench.report import Result, percentile
from tests.helpers import Mosquitto, mosquitto_binary

PREFIX = "benchw"
MACRO = 550


def config_text(broker: Mosquitto, state_dir: Path, native_port: int, packed_port: int) -> str:
    timeouts = "{request_s: 2, connect_s: 2, backoff_initial_s: 0.1, backoff_max_s: 0.5}"
    return f"""mqtt:
  host: {broker.host}
  port: {broker.port}
  formats: [json]
  json: {{prefix: {PREFIX}}}
state_dir: {state_dir}
writes:
  enabled: true
  allow: [{{target: "macro:500-599"}}]
  rate_limit: {{max_writes: 1000000, per_s: 1}}
machines:
  - {{id: native, host: 127.0.0.1, port: {native_port}, timeouts: {timeouts}}}
  - {{id: packed, transport: packed, address: "tcp:127.0.0.1:{packed_port}", timeouts: {timeouts}}}
"""


class CommandClient:
    """Publishes one command and waits for the reply with the same id."""

    def __init__(self, broker: Mosquitto) -> None:
        self._replies: dict[str, tuple[float, dict[str, Any]]] = {}
        self._arrived = threading.Condition()
        self.client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-writer-{id(self)}")
        subscribed = threading.Event()
        self.client.on_connect = lambda c, *a: c.subscribe(f"{PREFIX}/+/cmd/reply", qos=1)
        self.client.on_subscribe = lambda *a: subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect(broker.host, broker.port, keepalive=30)
        sock = self.client.socket()
        if isinstance(sock, socket.socket):  # the measuring client must not add Nagle's ~40 ms itself
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client.loop_start()
        if not subscribed.wait(10):
            raise RuntimeError("command client could not subscribe")

    def _on_message(self, client: paho.Client, userdata: Any, message: paho.MQTTMessage) -> None:
        received = time.perf_counter()
        try:
            reply = json.loads(message.payload)
        except ValueError:
            return
        with self._arrived:
            self._replies[str(reply.get("id"))] = (received, reply)
            self._arrived.notify_all()

    def write(self, machine: str, request_id: str, value: float, timeout: float = 10.0) -> tuple[float, dict[str, Any]]:
        body = json.dumps({"id": request_id, "target": f"macro:{MACRO}", "value": value})
        sent = time.perf_counter()
        self.client.publish(f"{PREFIX}/{machine}/cmd", body, qos=1)
        with self._arrived:
            if not self._arrived.wait_for(lambda: request_id in self._replies, timeout):
                raise TimeoutError(f"no reply to {request_id} on {PREFIX}/{machine}/cmd/reply within {timeout}s")
            received, reply = self._replies.pop(request_id)
        return received - sent, reply

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def wait_online(client: CommandClient, machine: str, timeout: float = 30.0) -> dict[str, Any]:
    """Retry a harmless write until the machine answers something other than 'not connected yet'."""
    deadline = time.monotonic() + timeout
    attempt = 0
    while True:
        attempt += 1
        try:
            _, reply = client.write(machine, f"probe-{attempt}", 0.0, timeout=5)
        except TimeoutError:
            reply = {"ok": False, "error": {"code": "timeout"}}
        code = (reply.get("error") or {}).get("code", "")
        if reply.get("ok") or code in ("not_supported",) or time.monotonic() > deadline:
            return reply
        time.sleep(0.2)


def run(quick: bool = False, writes: int | None = None) -> Result:
    count = writes or (10 if quick else 200)
    result = Result("writes", f"python -m bench writes{' --quick' if quick else ''}")
    binary = mosquitto_binary()
    if binary is None:
        result.status = "failed"
        result.notes.append("mosquitto is not installed")
        return result
    workdir = Path(tempfile.mkdtemp(prefix="bench-writes-"))
    broker = Mosquitto(binary)
    sim: SimProcess | None = None
    daemon: DaemonProcess | None = None
    client: CommandClient | None = None
    try:
        broker.start()
        sim = SimProcess(1, packed=True)
        packed_port = sim.packed_ports[0]
        assert packed_port is not None
        config = workdir / "edge.yaml"
        config.write_text(config_text(broker, workdir / "state", sim.ports[0], packed_port))
        daemon = DaemonProcess(config, workdir / "daemon.log")
        client = CommandClient(broker)
        for machine in ("native", "packed"):
            probe = wait_online(client, machine)
            if not probe.get("ok"):
                result.status = "pending"
                result.notes.append(f"{machine}: the command topic answered {json.dumps(probe)}; the write path "
                                    "(edge/command) is not working end to end yet, so no latency is reported")
                continue
            latencies = []
            failures = 0
            for i in range(count):
                latency, reply = client.write(machine, f"{machine}-{i}", round(i * 0.25, 3))
                latencies.append(latency)
                failures += 0 if reply.get("ok") else 1
            result.rows.append({"transport": "focas" if machine == "native" else machine, "writes": count,
                                "failed": failures, "p50_ms": percentile(latencies, 50) * 1000,
                                "p99_ms": percentile(latencies, 99) * 1000, "max_ms": max(latencies) * 1000})
        return result
    finally:
        if client is not None:
            client.close()
        if daemon is not None:
            daemon.stop()
        if sim is not None:
            sim.stop()
        broker.close()
        shutil.rmtree(workdir, ignore_errors=True)
