"""The daemon's collector settings: start-up objects frozen, young threshold raised, the rest kept."""

from __future__ import annotations

import gc

from edge.service.gc_tuning import YOUNG_THRESHOLD, tune_collector


def test_tuning_freezes_start_up_and_raises_only_the_young_threshold() -> None:
    before = gc.get_threshold()
    try:
        previous = tune_collector()
        assert previous == before
        assert gc.get_threshold() == (YOUNG_THRESHOLD, before[1], before[2])
        assert gc.get_freeze_count() > 0
        assert gc.isenabled()  # cyclic garbage is still collected
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)
