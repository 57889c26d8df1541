"""The daemon under pyinstrument: `python -m bench.profiled_daemon CONFIG OUT.txt` (stops on SIGTERM).

The profile covers the whole run; the text report (call tree) and a flat top list are written at exit, and the
session itself beside it (OUT.session.json; `python -m bench.profile_breakdown` gives its busy time by layer).
"""

from __future__ import annotations

import sys
from pathlib import Path

from pyinstrument import Profiler
from pyinstrument.renderers import ConsoleRenderer

from edge.service.daemon import run_daemon


def main() -> int:
    config, out = Path(sys.argv[1]), Path(sys.argv[2])
    profiler = Profiler(interval=0.001, async_mode="disabled")
    profiler.start()
    try:
        code = run_daemon(config)
    finally:
        profiler.stop()
        session = profiler.last_session
        assert session is not None
        tree = ConsoleRenderer(unicode=False, color=False, show_all=False, time="percent_of_total")
        flat = ConsoleRenderer(unicode=False, color=False, flat=True, time="percent_of_total")
        out.write_text(tree.render(session) + "\n\n==== flat ====\n" + flat.render(session))
        session.save(str(out.with_suffix(".session.json")))
    return code


if __name__ == "__main__":
    sys.exit(main())
