"""Results of one benchmark run: rows, target checks, the machine they ran on; printed and saved as JSON."""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent / "results"


@dataclass
class Check:
    """One target from the issue: `value` compared with `limit` (`<=` or `>=`)."""

    target: str
    value: float | None
    limit: float
    op: str  # "<=" or ">="
    unit: str = ""

    @property
    def met(self) -> bool | None:
        if self.value is None:
            return None
        return self.value <= self.limit if self.op == "<=" else self.value >= self.limit

    def describe(self) -> str:
        if self.value is None:
            return f"{self.target}: not measured"
        verdict = "MET" if self.met else "MISSED"
        return f"{self.target}: {fmt(self.value)}{self.unit} (target {self.op} {fmt(self.limit)}{self.unit}) {verdict}"


@dataclass
class Result:
    """What one benchmark returns: a table (rows of the same keys) plus target checks and notes."""

    name: str
    command: str
    rows: list[dict[str, Any]] = field(default_factory=list)
    checks: list[Check] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    status: str = "ok"  # or "pending" / "failed"


def machine_info() -> dict[str, Any]:
    """The machine the numbers came from (CPU model, cores, Python, load at the start)."""
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        model = platform.processor()
    load = os.getloadavg() if hasattr(os, "getloadavg") else (0.0, 0.0, 0.0)
    return {"cpu": model or platform.machine(), "cores": os.cpu_count(), "arch": platform.machine(),
            "python": sys.version.split()[0], "implementation": platform.python_implementation(),
            "kernel": platform.release(), "loadavg_1m": round(load[0], 2)}


def fmt(value: object) -> str:
    if isinstance(value, float):
        if value != value:  # NaN
            return "-"
        magnitude = abs(value)
        if magnitude >= 1000:
            return f"{value:,.0f}"
        if magnitude >= 100:
            return f"{value:.0f}"
        if magnitude >= 10:
            return f"{value:.1f}"
        return f"{value:.2f}"
    if value is None:
        return "-"
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:,}"
    return str(value)


def table(rows: Sequence[dict[str, Any]]) -> str:
    """Rows as an aligned text table (columns in first-seen key order; nested figures stay in the JSON only)."""
    if not rows:
        return "(no rows)"
    columns: list[str] = []
    for row in rows:
        columns.extend(k for k, v in row.items() if k not in columns and not isinstance(v, dict))
    cells = [[fmt(row.get(c)) for c in columns] for row in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines.extend("  ".join(v.rjust(w) if i else v.ljust(w) for i, (v, w) in enumerate(zip(r, widths, strict=True)))
                 for r in cells)
    return "\n".join(lines)


def render(result: Result) -> str:
    out = [f"== {result.name} ({result.status}) ==", f"command: {result.command}", table(result.rows)]
    out.extend(f"  target  {check.describe()}" for check in result.checks)
    out.extend(f"  note    {note}" for note in result.notes)
    return "\n".join(out)


def save(result: Result, machine: dict[str, Any], directory: Path = RESULTS_DIR) -> Path:
    """Write <name>.json (latest) and <name>-<time>.json (history) under `directory`."""
    directory.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    doc = {"benchmark": result.name, "status": result.status, "command": result.command,
           "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": machine, "rows": result.rows,
           "checks": [{**asdict(c), "met": c.met} for c in result.checks], "notes": result.notes}
    text = json.dumps(doc, indent=2, default=str)
    (directory / f"{result.name}-{stamp}.json").write_text(text)
    latest = directory / f"{result.name}.json"
    latest.write_text(text)
    return latest


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0..100), linear interpolation; NaN for no values."""
    if not values:
        return float("nan")
    ordered = sorted(values)
    if len(ordered) == 1:
        return ordered[0]
    position = (len(ordered) - 1) * q / 100
    low = int(position)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (position - low)


def spread(values: Sequence[float]) -> str:
    """'median (min..max)' of repeated measurements, to show how noisy they were."""
    if not values:
        return "-"
    if len(values) == 1:
        return fmt(values[0])
    return f"{fmt(statistics.median(values))} ({fmt(min(values))}..{fmt(max(values))})"
