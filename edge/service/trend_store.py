"""The plant page's 24 h timelines kept in state_dir, so a restart or an upgrade does not blank the day.

Only the day strips are kept (a byte per machine-minute, base64 in one JSON file, written atomically every
few minutes and at shutdown); the last hour's exact transitions, the sparklines and the alarm list start
afresh. Time between the last save and the restart is UNKNOWN: the gateway did not see it. A file that
cannot be read is logged and ignored (the page starts empty), never a reason to refuse to start.
"""

from __future__ import annotations

import asyncio
import base64
import json
import logging
from collections.abc import Iterable, Set
from pathlib import Path

from edge.service.trends import DAY_RING, Band, DayStrip, MachineTrend, TrendRecorder
from edge.statefile import write_atomically

log = logging.getLogger(__name__)

TRENDS_FILE = "plant-timelines.json"
SAVE_PERIOD_S = 300.0
FORMAT = 1


def save_trends(recorder: TrendRecorder, path: Path) -> None:
    now = recorder.clock()
    machines = {}
    for machine_id, trend in recorder.machines.items():
        day = trend.day
        day.advance(now)
        machines[machine_id] = {"minute": day.minute, "mark": day.mark, "seconds": day.seconds,
                                "slots": base64.b64encode(bytes(day.slots)).decode("ascii")}
    write_atomically(path, json.dumps({"format": FORMAT, "saved_at": now, "machines": machines}).encode())


def load_trends(recorder: TrendRecorder, path: Path, machine_ids: Set[str] | None = None) -> int:
    """Restore the day strips saved in `path` into `recorder` (only `machine_ids` when given); how many
    machines were restored."""
    try:
        document = json.loads(path.read_bytes())
    except FileNotFoundError:
        return 0
    except (OSError, ValueError) as exc:
        log.warning("plant page timelines not restored, starting empty path=%s error=%r", path, exc)
        return 0
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        log.warning("plant page timelines not restored: unknown format path=%s", path)
        return 0
    now = recorder.clock()
    restored = 0
    for machine_id, saved in dict(document.get("machines") or {}).items():
        if machine_ids is not None and machine_id not in machine_ids:
            continue
        try:
            strip = _strip(saved)
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("plant page timeline of one machine not restored machine=%s error=%r", machine_id, exc)
            continue
        if strip.mark > now:  # saved in the future (the clock was set back): nothing to trust
            continue
        trend = MachineTrend(now)
        trend.day = strip
        strip.advance(now)  # the gap since the save, as UNKNOWN
        recorder.machines[str(machine_id)] = trend
        restored += 1
    return restored


def _strip(saved: dict[str, object]) -> DayStrip:
    slots = base64.b64decode(str(saved["slots"]), validate=True)
    seconds = [float(s) for s in saved["seconds"]]  # type: ignore[attr-defined]
    if len(slots) != DAY_RING or len(seconds) != len(Band) or max(slots, default=0) >= len(Band):
        raise ValueError("slots or seconds of the wrong size")
    mark = float(saved["mark"])  # type: ignore[arg-type]
    strip = DayStrip(mark)
    strip.slots[:] = slots
    strip.minute = int(saved["minute"])  # type: ignore[call-overload]
    strip.seconds = seconds
    strip.band = Band.UNKNOWN  # from the save until the first sample after the restart
    return strip


async def keep_saved(recorder: TrendRecorder, state_dir: Path, period_s: float = SAVE_PERIOD_S) -> None:
    """Save every `period_s` until cancelled; a failed write is logged and tried again next time."""
    path = state_dir / TRENDS_FILE
    while True:
        await asyncio.sleep(period_s)
        try:
            save_trends(recorder, path)
        except OSError as exc:
            log.warning("plant page timelines not saved path=%s error=%r", path, exc)


def open_trends(state_dir: Path, machine_ids: Iterable[str]) -> TrendRecorder:
    """The daemon's recorder, with the day strips of the last run when state_dir has them (of the machines
    still configured)."""
    recorder = TrendRecorder()
    restored = load_trends(recorder, state_dir / TRENDS_FILE, set(machine_ids))
    if restored:
        log.info("plant page timelines restored machines=%d", restored)
    return recorder


def close_trends(recorder: TrendRecorder, state_dir: Path) -> None:
    """The last save, at shutdown; a failure is logged (the page loses at most the time since the last one)."""
    try:
        save_trends(recorder, state_dir / TRENDS_FILE)
    except OSError as exc:
        log.warning("plant page timelines not saved at shutdown error=%r", exc)
