"""Where the daemon's busy time goes, by layer: `python -m bench.profile_breakdown SESSION.json [--us-per-cycle N]`.

SESSION.json is a pyinstrument session (bench.profiled_daemon writes one beside its text report; a fleet run
gives it with `FleetOptions(profile_to=...)`). Each sample is charged to the layer of the first frame from its
leaf that belongs to the daemon (a C call to the Python code that made it; asyncio's transport frames to the
code that wrote or read). Samples waiting in epoll are idle and left out. pyinstrument times by the wall clock
and adds a cost per Python call, so the shares are rough: a socket send preempted by the process it woke counts
as busy, and deep await chains look dearer than they are.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
from pathlib import Path

IDLE_LEAVES = frozenset({"epoll.poll", "select", "poll"})
SOCKET_IO = "FOCAS socket I/O and frame decoding (the floor's own work)"
LOOP = "event loop (run_once, handles, futures)"
_FOCAS_IO = frozenset({"data_received", "_wake", "send", "_roundtrip", "arrival", "next_frame", "feed", "_next_frame"})
_CLOCK = frozenset({"_observe_clock", "_probe_clock_before", "_probe_before", "_probe_clock"})
_ENCODE = frozenset({"node.py", "ddata.py", "payload.py", "device_table.py", "aliases.py", "alias_journal.py"})
_LINE = re.compile(r"\x01l(\d+)")


def _frame(record: str) -> tuple[str, str, int]:
    """(function, path below the tree, line) of one pyinstrument frame identifier."""
    parts = record.split("\x00")
    path = parts[1] if len(parts) > 1 else ""
    for marker in ("site-packages/", "python3.11/", "/edge/", "/bench/"):
        if marker in path:
            path = (marker.strip("/") + "/" if marker in ("/edge/", "/bench/") else "") + path.split(marker, 1)[1]
            break
    line = _LINE.search(parts[2]) if len(parts) > 2 else None
    return parts[0], path, int(line.group(1)) if line else 0


def _edge_layer(name: str, path: str, line: int) -> str:
    if path in ("edge/publish/mqtt.py", "edge/publish/mqtt_wire.py"):
        return "MQTT send (publish packets, flush)"
    if path.startswith("edge/focas/"):
        if name in _FOCAS_IO and path in ("edge/focas/client.py", "edge/focas/frame.py"):
            return SOCKET_IO
        if path in ("edge/focas/session.py", "edge/focas/deadline.py"):
            return "FOCAS session (lock, request deadline)"
        return "FOCAS client (prepared request, answer split, decode of what moved)"
    if path.startswith("edge/collect/"):
        if path == "edge/collect/poller.py" and name == "_tick":
            return "tick (timing, the change loop over moved reads)"
        if name in _CLOCK or path.startswith("edge/collect/clock") or path.endswith("answer_time.py"):
            return "CNC clock (feed, probes, stamps)"
        if path == "edge/collect/changes.py":
            return "Sample building (in report)" if name == "report" and line >= 66 else "change detection (report)"
        if path in ("edge/collect/poller.py", "edge/collect/tickgrid.py", "edge/collect/plan.py",
                    "edge/collect/tick_batch.py"):
            return "poll loop and scheduling (grid, schedule, await chain)"
        return "collect: stats, plant state, utilisation"
    if path.startswith(("edge/publish/spool", "edge/publish/replay")):
        return "spool"
    if path.startswith("edge/publish/") and path.rsplit("/", 1)[-1] in _ENCODE:
        return "Sparkplug encode (DDATA bytes, last values)"
    if path.startswith("edge/publish/") or path == "edge/service/outputs.py":
        return "publisher chain (outputs, publisher, session, link, outbox)"
    if path.startswith("edge/service/trend"):
        return "trends (status page)"
    if path.startswith("edge/service/gc_tuning"):
        return "garbage collection (paced)"
    return "other daemon work (config, state files, status)"


def layer(stack: list[tuple[str, str, int]]) -> str:
    """The layer a sample's time is charged to."""
    via_transport = False
    for name, path, line in reversed(stack):
        if path.startswith("asyncio/"):
            if path.startswith(("asyncio/base_events", "asyncio/events", "asyncio/runners")):
                return LOOP
            via_transport = via_transport or path.startswith("asyncio/selector_events")
            continue
        if path.startswith("paho/"):
            return "MQTT send (publish packets, flush)"
        if path.startswith("edge/"):
            found = _edge_layer(name, path, line)
            return SOCKET_IO if via_transport and found.startswith("FOCAS") else found
    return LOOP


def breakdown(session: dict[str, object]) -> tuple[float, dict[str, float]]:
    """Busy seconds and seconds by layer."""
    layers: collections.Counter[str] = collections.Counter()
    busy = 0.0
    for stack, seconds in session["frame_records"]:  # type: ignore[attr-defined]
        frames = [_frame(record) for record in stack]
        if frames[-1][0] in IDLE_LEAVES:
            continue
        busy += seconds
        layers[layer(frames)] += seconds
    return busy, dict(layers.most_common())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--us-per-cycle", type=float, default=None,
                        help="the unprofiled run's CPU per machine-cycle: shares shown as microseconds of it too")
    args = parser.parse_args()
    busy, layers = breakdown(json.loads(args.session.read_text()))
    print(f"busy {busy:.2f} s of the main thread")
    for name, seconds in layers.items():
        share = seconds / busy if busy else 0.0
        extra = f" | ~{share * args.us_per_cycle:.0f} µs" if args.us_per_cycle else ""
        print(f"| {name} | {100 * share:.1f} %{extra} |")


if __name__ == "__main__":
    main()
