"""Garbage-collector settings for the long-running daemon.

Every poll tick allocates and frees small objects (samples, answer tuples, lists); reference counting frees
almost all of them. With CPython's default young-generation threshold (700) the cyclic collector still
ran ~20 young collections a second at 100 machines and a full one every few seconds over the ~100k
long-lived objects of the process (modules, configuration, plans, metric tables): 5-8 % of the gateway's
CPU in `python -m bench fleet`. So the objects alive after start-up are frozen out of the collector and
the young threshold is raised. Cyclic garbage (rare here) is still collected, only less often.
"""

from __future__ import annotations

import gc

YOUNG_THRESHOLD = 20_000  # allocations (net) between young collections; CPython's default is 700


def tune_collector() -> tuple[int, int, int]:
    """Freeze what start-up built and raise the young threshold; returns the previous thresholds."""
    previous = gc.get_threshold()
    gc.collect()  # start-up's own garbage first, so it is not frozen
    gc.freeze()
    gc.set_threshold(YOUNG_THRESHOLD, previous[1], previous[2])
    return previous
