"""The daemon under pyinstrument: `python -m bench.profiled_daemon CONFIG OUT.txt` (stops on SIGTERM).

The profile covers the whole run; the text report (call tree) and a flat top list are written at exit, and the
session itself beside it (OUT.session.json; `python -m bench.profile_breakdown` gives its busy time by layer).
With FOCAS_PROFILE_AFTER_S=N in the environment it starts N whole seconds after the daemon (SIGALRM), and with
FOCAS_PROFILE_FOR_S=M it stops M seconds later: a fleet's start-up (1,000 births) and shutdown left out of a
profile of its steady state.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from pyinstrument import Profiler
from pyinstrument.renderers import ConsoleRenderer

from edge.service.daemon import run_daemon


def main() -> int:
    config, out = Path(sys.argv[1]), Path(sys.argv[2])
    profiler = Profiler(interval=0.001, async_mode="disabled")
    after_s = int(os.environ.get("FOCAS_PROFILE_AFTER_S", "0"))
    for_s = int(os.environ.get("FOCAS_PROFILE_FOR_S", "0"))

    def alarm(*_: object) -> None:  # a signal handler runs in the main thread, between bytecodes
        if not profiler.is_running:
            profiler.start()
            signal.alarm(for_s)  # 0: no stop until the daemon's end
        else:
            profiler.stop()

    if after_s > 0:
        signal.signal(signal.SIGALRM, alarm)
        signal.alarm(after_s)
    else:
        profiler.start()
    try:
        code = run_daemon(config)
    finally:
        signal.alarm(0)
        if profiler.is_running:
            profiler.stop()
        elif profiler.last_session is None:  # ended before it began: an empty profile rather than none
            profiler.start()
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
