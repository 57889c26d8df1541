"""Plain JSON topics for consumers that do not speak Sparkplug (docs/topics.md documents each one).

    <prefix>/_gateway/online               retained "online" / "offline" (the Will of the JSON connection)
    <prefix>/<machine>/online              retained "online" / "offline"
    <prefix>/<machine>/state/<metric name> retained {"value", "quality", "timestamp", "ts", "type"}; while the
                                           machine's session is down: quality "STALE" and "stale_since"
    <prefix>/<machine>/events/alarm        not retained, one message per event (replayed ones: "historical")
    <prefix>/<machine>/history/<metric>    not retained: values replayed from the store-and-forward spool
    <prefix>/<machine>/cmd                 subscribed: write requests (parsed by the command layer)
    <prefix>/<machine>/cmd/reply           replies (or the MQTT 5 response topic of the request)

Sans-IO: builds (topic, bytes) pairs; the publisher sends them.
"""

from __future__ import annotations

import itertools
import json
import math
from datetime import UTC, datetime

from edge.publish.node import Outgoing, check_id
from edge.samples import Quality, Sample

GATEWAY = "_gateway"
ONLINE = b"online"
OFFLINE = b"offline"


def iso_utc(timestamp_ms: int) -> str:
    """ISO 8601 UTC with milliseconds, e.g. 2024-05-01T12:00:00.123Z."""
    dt = datetime.fromtimestamp(timestamp_ms / 1000, tz=UTC)
    return dt.strftime("%Y-%m-%dT%H:%M:%S.") + f"{timestamp_ms % 1000:03d}Z"


def json_value(value: object) -> object:
    """JSON has no NaN/Infinity: those become null; everything else passes to json.dumps as is."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def topic_level(name: str) -> str:
    """A metric name as topic levels: keep its '/' folders, replace the MQTT wildcards."""
    return name.replace("+", "_").replace("#", "_")


def sample_document(sample: Sample) -> dict[str, object]:
    doc: dict[str, object] = {
        "value": json_value(sample.value),
        "quality": Quality(sample.quality).name,
        "timestamp": iso_utc(sample.timestamp_ms),
        "ts": sample.timestamp_ms,
        "type": sample.type.value,
    }
    if sample.historical:
        doc["historical"] = True
    return doc


def encode(doc: object) -> bytes:
    return json.dumps(doc, separators=(",", ":"), default=str, allow_nan=False).encode("utf-8")


class JsonTopics:
    """Topic names and message bodies under one prefix.

    Every JSON document carries `seq`: one counter per daemon process over all documents, strictly
    increasing in publish order (it restarts at 0 with the process). Replayed documents also carry
    `spool_id`, the spool row they came from, which is the same when a crash makes a replay repeat.
    """

    def __init__(self, prefix: str) -> None:
        prefix = prefix.strip("/")
        if not prefix or "+" in prefix or "#" in prefix:
            raise ValueError(f"JSON topic prefix {prefix!r}: expected a non-empty topic without + or #")
        self.prefix = prefix
        self.gateway_status_topic = f"{prefix}/{GATEWAY}/online"
        self.command_filter = f"{prefix}/+/cmd"
        self._seq = itertools.count()

    def _numbered(self, doc: dict[str, object], spool_id: int | None) -> bytes:
        doc["seq"] = next(self._seq)
        if spool_id is not None:
            doc["spool_id"] = spool_id
        return encode(doc)

    def gateway_online(self) -> Outgoing:
        return Outgoing(self.gateway_status_topic, ONLINE, qos=1, retain=True)

    def gateway_offline(self) -> Outgoing:
        """Published on clean stop and registered as the Will of the JSON connection."""
        return Outgoing(self.gateway_status_topic, OFFLINE, qos=1, retain=True)

    def machine_status(self, machine: str, online: bool) -> Outgoing:
        check_id("machine id", machine)
        return Outgoing(f"{self.prefix}/{machine}/online", ONLINE if online else OFFLINE, qos=1, retain=True)

    def state(self, machine: str, sample: Sample, stale_since_ms: int | None = None) -> Outgoing:
        """The retained current value; with `stale_since_ms` (the machine's session is down since then) the
        last value is restated with quality STALE, so a late subscriber never reads GOOD from a dead machine."""
        doc = sample_document(sample)
        if stale_since_ms is not None:
            doc["quality"] = Quality.STALE.name
            doc["stale_since"] = iso_utc(stale_since_ms)
        return Outgoing(f"{self.prefix}/{machine}/state/{topic_level(sample.name)}", self._numbered(doc, None),
                        qos=0, retain=True)

    def event(self, machine: str, sample: Sample, spool_id: int | None = None) -> Outgoing:
        doc = sample_document(sample)
        doc["name"] = sample.name
        return Outgoing(f"{self.prefix}/{machine}/events/alarm", self._numbered(doc, spool_id), qos=1,
                        retain=False)

    def history(self, machine: str, sample: Sample, spool_id: int) -> Outgoing:
        """A value replayed from the spool: never retained (it must not replace the current state)."""
        doc = sample_document(sample)
        doc["name"] = sample.name
        doc["historical"] = True
        return Outgoing(f"{self.prefix}/{machine}/history/{topic_level(sample.name)}",
                        self._numbered(doc, spool_id), qos=1, retain=False)

    def reply_topic(self, machine: str) -> str:
        return f"{self.prefix}/{machine}/cmd/reply"

    def command_machine(self, topic: str) -> str | None:
        """The machine id of a `<prefix>/<machine>/cmd` topic, else None."""
        head = f"{self.prefix}/"
        if not topic.startswith(head) or not topic.endswith("/cmd"):
            return None
        machine = topic[len(head):-len("/cmd")]
        return machine if machine and "/" not in machine else None
