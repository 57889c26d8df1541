"""The compact live view of `make run`: one line per machine, redrawn in place, and a tail of recent events.

The machine lines come from the daemon's own state (the same document as the status page), the events
from what a subscriber actually receives on the broker (births, deaths, alarm events), so the view shows
both what is polled and that it is published. On a terminal the block is redrawn in place; into a pipe
or a file each changed block is printed whole, so a log of the run stays readable.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections import deque
from collections.abc import Callable
from typing import Any, TextIO

from edge.service.daemon_view import DaemonView
from edge.service.status_page import RateMeter, status_document

EVENT_KINDS = ("NBIRTH", "DBIRTH", "NDEATH", "DDEATH", "STATE")
SHOWN_VALUES = (("Status/Run", ""), ("Program/Number", "O"), ("Spindle/1/Speed", "S "), ("Counters/Parts", "parts "))


def is_event(line: str) -> bool:
    """Births, deaths, host state and JSON alarm events: what is worth a line in the tail."""
    return line.startswith(EVENT_KINDS) or "/events/" in line


def event_topic(line: str) -> str:
    """The kind and topic of a decoded event line (`JSON   focas/m1/events/alarm = ...` -> `JSON focas/...`)."""
    return " ".join(line.split()[:2])


def machine_line(machine: dict[str, Any], width: int) -> str:
    values = {v["name"]: v["value"] for v in machine["values"]}
    state = "connected" if machine["connected"] else "OFFLINE  "
    parts = [f"{machine['id']:<{width}}", f"{machine['series'] or '?':<7}", state]
    parts += [f"{label}{values.get(name, '(none)')}" for name, label in SHOWN_VALUES]
    alarms = "; ".join(f"{a['number']} {a['message']}" for a in machine["alarms"])
    parts.append(f"alarms: {alarms or 'none'}")
    if machine["dropped"]:
        parts.append(f"dropped: {', '.join(machine['dropped'])}")
    return "  ".join(parts)


class LiveView:
    """Draws the daemon's machines and the event tail to `out` every `interval` seconds."""

    def __init__(self, daemon: DaemonView, out: TextIO | None = None, tail: int = 12,
                 is_tty: bool | None = None, clock: Callable[[], float] = time.time) -> None:
        self.daemon = daemon
        self.out = out or sys.stdout
        self.is_tty = self.out.isatty() if is_tty is None else is_tty
        self.events: deque[str] = deque(maxlen=tail)
        self.messages = 0
        self._meter = RateMeter()
        self._clock = clock
        self._drawn_lines = 0
        self._last_block: list[str] = []
        self._repeats: dict[str, int] = {}  # topic -> how many events its one tail line stands for

    def on_line(self, line: str) -> None:
        """A decoded line from the watcher (its MQTT thread): counted, and kept if it is an event.

        Events on a topic already in the tail (an alarm-history backlog, say, even interleaved with other
        machines' backlogs) take that topic's one line, moved to the end with a count, so bursts never
        push the births out of the tail.
        """
        self.messages += 1
        if not is_event(line):
            return
        stamp = time.strftime("%H:%M:%S ", time.localtime(self._clock()))
        topic = event_topic(line)
        repeats = self._repeats.get(topic, 0) + 1
        if repeats > 1:
            self.events = deque((e for e in self.events if event_topic(e.split(" ", 1)[1]) != topic),
                                maxlen=self.events.maxlen)
            line = f"{line}  (x{repeats} on this topic)"
        if self.events.maxlen is not None and len(self.events) == self.events.maxlen:
            self._repeats.pop(event_topic(self.events[0].split(" ", 1)[1]), None)
        self.events.append(stamp + line)
        self._repeats[topic] = repeats

    def block(self) -> list[str]:
        doc = status_document(self.daemon, self._meter)
        gateway = doc["gateway"]
        width = max((len(m["id"]) for m in doc["machines"]), default=4)
        head = (f"== {gateway['machines_connected']} of {gateway['machines']} machines connected, broker "
                f"{'connected' if gateway['broker_connected'] else 'DOWN'}, {self.messages} messages received "
                f"(--raw shows each one)")
        lines = [head, *(machine_line(m, width) for m in doc["machines"]), "-- recent events"]
        return lines + (list(self.events) or ["(none yet)"])

    def draw(self) -> None:
        lines = self.block()
        if self.is_tty:
            if self._drawn_lines:
                self.out.write(f"\x1b[{self._drawn_lines}F\x1b[J")  # back to the block's first line, clear below
            self.out.write("\n".join(lines) + "\n")
            self._drawn_lines = len(lines)
        elif lines[1:] != self._last_block[1:]:  # the message count alone is no news in a log
            self.out.write("\n".join(lines) + "\n")
        self._last_block = lines
        self.out.flush()

    async def run(self, interval: float = 1.0) -> None:
        """Redraw until cancelled."""
        while True:
            self.draw()
            await asyncio.sleep(interval)
