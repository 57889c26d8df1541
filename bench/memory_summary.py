"""`python -m bench.memory_summary FILE [--machines N] [--top 25]`: a tracemalloc dump as a table.

FILE is what `python -m bench fleet --tracemalloc FILE` (bench/memory_daemon.py) wrote: live Python
allocations by module and by allocation site. With --machines, each row also shows bytes per machine, the
figure docs/performance.md gives for a fleet's memory.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--machines", type=int, default=0)
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args(argv)
    doc = json.loads(args.file.read_text())
    per = args.machines or 0
    total = doc["total_bytes"]
    each = f", {total / per / 1e3:.1f} kB per machine" if per else ""
    print(f"live Python allocations: {total / 1e6:.1f} MB{each}")
    if "after_full_collection" in doc:  # what a full collection freed: cyclic garbage the freezes kept
        after = doc["after_full_collection"]["total_bytes"]
        print(f"after a full collection ({doc['collected_objects']:,d} objects freed): {after / 1e6:.1f} MB"
              + (f", {after / per / 1e3:.1f} kB per machine" if per else ""))
        kept = {row["module"]: row["bytes"] for row in doc["after_full_collection"]["modules"]}
        freed = sorted(((row["bytes"] - kept.get(row["module"], 0), row["module"]) for row in doc["modules"]),
                       reverse=True)
        print("  freed by module: " + ", ".join(f"{m} {b / 1e6:.2f} MB" for b, m in freed[:8] if b > 0))
    for title, rows, key in (("module", doc["modules"], "module"), ("site", doc["sites"], "site")):
        print(f"\n{'by ' + title:<48} {'MB':>8} {'share':>6} {'blocks':>9}" + (f" {'B/machine':>10}" if per else ""))
        for row in rows[:args.top]:
            line = f"{row[key]:<48} {row['bytes'] / 1e6:8.2f} {100 * row['bytes'] / total:5.1f}% {row['blocks']:9,d}"
            print(line + (f" {row['bytes'] / per:10,.0f}" if per else ""))


if __name__ == "__main__":
    main()
