"""A live, decoded view of what focas-edge publishes: Sparkplug births/data/deaths and JSON topics.

Keeps the alias -> (name, type) map from each NBIRTH/DBIRTH so DATA messages (alias only, no
datatype) print with their names and values. Used by `focas-edge watch` and by `make run`.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from datetime import UTC, datetime

import paho.mqtt.client as paho
from paho.mqtt.enums import CallbackAPIVersion

from edge.publish import PublishSettings, apply_credentials
from edge.publish import payload as spb
from edge.samples import MetricType, Quality

Printer = Callable[[str], None]


def _clock(ms: int) -> str:
    return datetime.fromtimestamp(ms / 1000, UTC).strftime("%H:%M:%S.%f")[:-3]


def _value_text(value: object) -> str:
    if value is None or value == "":
        return "(none)"
    if isinstance(value, float):
        return f"{value:.4f}".rstrip("0").rstrip(".") if value == value else "NaN"
    if isinstance(value, str):
        return value if len(value) <= 60 else value[:57] + "..."
    return str(value)


class SparkplugDecoder:
    """Turns Sparkplug messages into readable lines; remembers aliases per node/device."""

    def __init__(self) -> None:
        self._aliases: dict[tuple[str, ...], dict[int, tuple[str, MetricType]]] = {}

    def lines(self, topic: str, data: bytes) -> list[str]:
        parts = topic.split("/")
        if len(parts) == 3 and parts[:2] == ["spBv1.0", "STATE"]:  # Sparkplug 3.0: spBv1.0/STATE/<host_id>
            return [f"STATE  host={parts[2]} {data.decode(errors='replace')}"]
        if len(parts) < 4 or parts[0] != "spBv1.0":
            return []
        kind = parts[2]
        node = tuple(parts[1:2] + parts[3:4])
        device = parts[4] if len(parts) > 4 else ""
        key = (*node, device)
        label = f"{parts[3]}/{device}" if device else parts[3]
        try:
            payload = spb.decode(data)
        except Exception as exc:  # a watcher must survive any payload
            return [f"{kind:<7}{label}: undecodable payload ({exc})"]
        head = f"{kind:<7}{label}" + (f" seq={payload.seq}" if payload.HasField("seq") else "")
        if kind in ("NDEATH", "DDEATH"):
            return [head]
        aliases = self._aliases.setdefault(key, {})
        if kind in ("NBIRTH", "DBIRTH"):
            aliases.clear()
        out = [head + f" ({len(payload.metrics)} metrics)"] if kind.endswith("BIRTH") else []
        for metric in payload.metrics:
            name, mtype = metric.name, spb.METRIC_TYPE.get(metric.datatype, MetricType.STRING)
            if metric.HasField("alias"):
                if kind.endswith("BIRTH"):
                    aliases[metric.alias] = (name, mtype)
                elif not name:
                    name, mtype = aliases.get(metric.alias, (f"alias {metric.alias}", MetricType.STRING))
            try:
                value: object = spb.get_value(metric, mtype)
            except ValueError:
                value = "?"
            quality = spb.quality_of(metric)
            flags = "" if quality is Quality.GOOD else f" [{quality.name}]"
            if metric.is_historical:
                flags += " [historical]"
            stamp = f" @{_clock(metric.timestamp)}" if metric.HasField("timestamp") else ""
            line = f"  {name} = {_value_text(value)}{flags}{stamp}"
            if kind.endswith("BIRTH"):
                out.append(line)
            else:
                out.append(f"{head}  {line.strip()}")
        return out


def json_lines(topic: str, data: bytes) -> list[str]:
    text = data.decode(errors="replace")
    try:
        doc = json.loads(text)
    except ValueError:
        return [f"JSON   {topic} {text}"]
    if isinstance(doc, dict) and "value" in doc:
        quality = "" if doc.get("quality") in (None, "GOOD") else f" [{doc['quality']}]"
        stamp = f" @{_clock(int(doc['ts']))}" if isinstance(doc.get("ts"), int) else ""
        return [f"JSON   {topic} = {_value_text(doc['value'])}{quality}{stamp}"]
    return [f"JSON   {topic} {text[:200]}"]


class Watcher:
    """Subscribes to Sparkplug and JSON topics and prints each message as readable lines."""

    def __init__(self, host: str, port: int, topics: list[str], printer: Printer = print,
                 show_births: bool = True, credentials: PublishSettings | None = None) -> None:
        self.topics = topics
        self.printer = printer
        self.show_births = show_births
        self.decoder = SparkplugDecoder()
        self._lock = threading.Lock()
        self.count = 0
        self.node_death_seen = threading.Event()  # the demo waits for the daemon's NDEATH before it stops
        self.client = paho.Client(CallbackAPIVersion.VERSION2, client_id=f"focas-edge-watch-{id(self):x}")
        self.client.on_connect = lambda client, *_: client.subscribe([(t, 0) for t in self.topics])
        self.client.on_message = self._on_message
        if credentials is not None:
            apply_credentials(self.client, credentials)
        self.client.reconnect_delay_set(1, 10)
        self.client.connect_async(host, port, keepalive=30)

    def start(self) -> None:
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        data = bytes(msg.payload)
        if "/NDEATH/" in msg.topic:
            self.node_death_seen.set()
        if msg.topic.startswith("spBv1.0/"):
            lines = self.decoder.lines(msg.topic, data)
            if not self.show_births and lines and "BIRTH" in lines[0][:7]:
                lines = lines[:1]
        else:
            lines = json_lines(msg.topic, data)
        if msg.retain:  # kept by the broker from earlier: it may predate this run
            lines = [line + " (retained)" for line in lines]
        with self._lock:
            self.count += 1
            for line in lines:
                self.printer(line)
