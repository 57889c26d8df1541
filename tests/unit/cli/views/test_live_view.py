"""The compact view of `make run`: redrawn in place on a terminal, whole blocks into a pipe, events kept."""

from __future__ import annotations

import io
from typing import Any

from edge.cli.views.live_view import LiveView, is_event, machine_line


class FixedView(LiveView):
    def __init__(self, blocks: list[list[str]], is_tty: bool) -> None:
        super().__init__(daemon=None, out=io.StringIO(), is_tty=is_tty)  # type: ignore[arg-type]
        self._blocks = blocks

    def block(self) -> list[str]:
        return self._blocks.pop(0)


def test_a_terminal_gets_the_block_redrawn_in_place() -> None:
    view = FixedView([["== 1 of 1", "m1 START", "-- recent events"], ["== 1 of 1", "m1 STOP", "-- recent events"]],
                     is_tty=True)
    view.draw()
    view.draw()
    out = view.out.getvalue()  # type: ignore[attr-defined]
    first, second = out.split("\x1b[3F\x1b[J")
    assert first == "== 1 of 1\nm1 START\n-- recent events\n"
    assert second == "== 1 of 1\nm1 STOP\n-- recent events\n"


def test_a_pipe_gets_each_changed_block_once() -> None:
    view = FixedView([["== 5 messages", "m1 START"], ["== 9 messages", "m1 START"], ["== 12 messages", "m1 STOP"]],
                     is_tty=False)
    for _ in range(3):
        view.draw()
    out = view.out.getvalue()  # type: ignore[attr-defined]
    assert "\x1b" not in out
    assert out == "== 5 messages\nm1 START\n== 12 messages\nm1 STOP\n"


def test_events_are_births_deaths_and_alarm_events_and_every_line_is_counted() -> None:
    view = LiveView(daemon=None, out=io.StringIO(), tail=2, is_tty=False, clock=lambda: 0.0)  # type: ignore[arg-type]
    for line in ["DDATA  gw/m1 seq=3  Status/Run = START", "DBIRTH gw/m1 seq=1 (30 metrics)",
                 "JSON   focas/m1/events/alarm {\"event\": \"raised\"}", "NDEATH gw"]:
        view.on_line(line)
    assert view.messages == 4
    assert [e.split(" ", 1)[1] for e in view.events] == ["JSON   focas/m1/events/alarm {\"event\": \"raised\"}",
                                                         "NDEATH gw"]
    assert not is_event("DDATA  gw/m1 seq=3  Status/Run = START")


def test_a_machine_line_shows_missing_values_as_none() -> None:
    machine: dict[str, Any] = {"id": "m1", "series": "30i-BM", "connected": False, "dropped": ["ReadMacros"],
                               "alarms": [{"number": 1001, "message": "OVERHEAT"}],
                               "values": [{"name": "Status/Run", "value": "STOP"}]}
    assert machine_line(machine, 4) == ("m1    30i-BM   OFFLINE    STOP  O(none)  S (none)  parts (none)  "
                                        "alarms: 1001 OVERHEAT  dropped: ReadMacros")


def test_a_burst_on_one_topic_takes_one_line_so_births_stay_in_the_tail() -> None:
    view = LiveView(daemon=None, out=io.StringIO(), tail=3, is_tty=False, clock=lambda: 0.0)  # type: ignore[arg-type]
    view.on_line("DBIRTH gw/m1 seq=1 (30 metrics)")
    for n in range(40):  # an alarm-history backlog read at connect
        view.on_line(f"JSON   focas/m1/events/alarm = {{\"number\": {n}}}")
    view.on_line("DBIRTH gw/m2 seq=2 (31 metrics)")
    tail = [e.split(" ", 1)[1] for e in view.events]
    assert tail == ["DBIRTH gw/m1 seq=1 (30 metrics)",
                    "JSON   focas/m1/events/alarm = {\"number\": 39}  (x40 on this topic)",
                    "DBIRTH gw/m2 seq=2 (31 metrics)"]


def test_interleaved_bursts_of_several_machines_keep_every_birth_in_the_tail() -> None:
    view = LiveView(daemon=None, out=io.StringIO(), is_tty=False, clock=lambda: 0.0)  # type: ignore[arg-type]
    machines = ["m1", "m2", "m3", "m4"]
    view.on_line("NBIRTH gw seq=0 (12 metrics)")
    for m in machines:
        view.on_line(f"DBIRTH gw/{m} seq=1 (30 metrics)")
    for n in range(40):  # every machine's alarm-history backlog at once, interleaved
        for m in machines:
            view.on_line(f"JSON   focas/{m}/events/alarm = {{\"number\": {n}}}")
    tail = [e.split(" ", 1)[1] for e in view.events]
    assert [line for line in tail if line.startswith("DBIRTH")] == [f"DBIRTH gw/{m} seq=1 (30 metrics)"
                                                                     for m in machines]
    assert tail[-1] == "JSON   focas/m4/events/alarm = {\"number\": 39}  (x40 on this topic)"
    assert len(tail) == 9
