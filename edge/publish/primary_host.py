"""Primary Host Application STATE tracking (Sparkplug 3.0 §1.3 of shared/docs/sparkplug.md), sans-IO.

The host publishes `spBv1.0/STATE/<host_id>` = {"online": bool, "timestamp": ms}, retained, with a Will
carrying online=false and the timestamp of its birth. An edge node births only after a valid online STATE,
and on a valid offline it must send NDEATH and reconnect. A STATE whose timestamp is older than the last one
seen is a stale Will of an earlier host session and is ignored; the last timestamp therefore outlives our
own MQTT sessions, while "online" must be re-learned in each new session.
"""

from __future__ import annotations

import enum
import json
import logging

log = logging.getLogger(__name__)


class StateVerdict(enum.Enum):
    ONLINE = "online"
    OFFLINE = "offline"
    IGNORED = "ignored"


class PrimaryHost:
    """What we believe about the configured primary host."""

    def __init__(self, host_id: str) -> None:
        if not host_id or any(c in host_id for c in "+/#"):
            raise ValueError(f"primary host id {host_id!r}: expected a non-empty string without + / #")
        self.host_id = host_id
        self.topic = f"spBv1.0/STATE/{host_id}"
        self.online = False
        self.last_timestamp: int | None = None
        self.ignored = 0

    def new_session(self) -> None:
        """Our MQTT session restarted: wait for a STATE again, but remember the last timestamp."""
        self.online = False

    def on_state(self, topic: str, payload: bytes) -> StateVerdict:
        """Apply one STATE message and say what changed."""
        if topic.rsplit("/", 1)[-1] != self.host_id:
            return self._ignore(f"topic {topic!r} is not the STATE of host {self.host_id!r}")
        try:
            doc = json.loads(payload.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            return self._ignore(f"STATE payload is not JSON: {exc}")
        online = doc.get("online") if isinstance(doc, dict) else None
        timestamp = doc.get("timestamp") if isinstance(doc, dict) else None
        if not isinstance(online, bool) or not isinstance(timestamp, int) or isinstance(timestamp, bool):
            return self._ignore(f'STATE payload: expected {{"online": bool, "timestamp": int}}, got {doc!r}')
        if self.last_timestamp is not None and timestamp < self.last_timestamp:
            return self._ignore(f"stale STATE online={online} timestamp={timestamp} < "
                                f"last seen {self.last_timestamp}")
        self.last_timestamp = timestamp
        self.online = online
        log.info("primary host state host=%s online=%s timestamp=%d", self.host_id, online, timestamp)
        return StateVerdict.ONLINE if online else StateVerdict.OFFLINE

    def _ignore(self, reason: str) -> StateVerdict:
        self.ignored += 1
        log.warning("STATE ignored host=%s reason=%s", self.host_id, reason)
        return StateVerdict.IGNORED
