"""The daemon's collector settings: start-up objects frozen, young threshold raised, the rest kept."""

from __future__ import annotations

import asyncio
import gc
import weakref

from edge.service.gc_tuning import FREEZE_EVERY, YOUNG_THRESHOLD, CollectorKeeper, settle, tune_collector


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


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_settle_freezes_what_was_built_after_start_up() -> None:
    try:
        gc.freeze()
        before = gc.get_freeze_count()
        built = [[i] for i in range(1000)]  # lists (always tracked): built after the freeze
        frozen, held_s = settle()
        assert frozen >= before + len(built)
        assert held_s >= 0
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()


def test_keeper_settles_once_every_machine_started_is_born() -> None:
    born = [False]
    clock = FakeClock()
    keeper = CollectorKeeper(lambda: born[0], clock=clock, limit_s=120, recycle_s=3600)
    try:
        assert not keeper.step()  # no machine started yet: nothing to freeze
        keeper.machines_started()
        clock.now = 5
        assert not keeper.step()  # started, not born
        born[0] = True
        assert keeper.step()
        assert keeper.settled == 1
        clock.now = 6
        assert not keeper.step()  # settled once per start, not every check
        keeper.machines_started()  # a reload started machines
        assert keeper.step()
        assert keeper.settled == 2
    finally:
        gc.unfreeze()


def test_keeper_settles_after_the_limit_when_a_machine_never_answers() -> None:
    clock = FakeClock()
    keeper = CollectorKeeper(lambda: False, clock=clock, limit_s=120, recycle_s=3600)
    try:
        keeper.machines_started()
        clock.now = 119
        assert not keeper.step()
        clock.now = 120
        assert keeper.step()
    finally:
        gc.unfreeze()


def test_keeper_recycles_so_frozen_cycles_are_freed() -> None:
    class Session:
        pass

    clock = FakeClock()
    keeper = CollectorKeeper(lambda: True, clock=clock, limit_s=120, recycle_s=3600)
    try:
        session = Session()
        session.me = session  # type: ignore[attr-defined]  # a cycle, as a transport and its protocol make
        alive = weakref.ref(session)
        keeper.machines_started()
        assert keeper.step()  # frozen with the machine's other objects
        del session
        gc.collect()
        assert alive() is not None  # a frozen cycle is never examined
        clock.now = 3600
        assert keeper.step()  # the hourly recycle unfreezes and collects everything
        assert alive() is None
    finally:
        gc.unfreeze()


async def test_keeper_runs_young_collections_by_the_clock_and_freezes_their_survivors() -> None:
    """The allocation count can hover near zero in a steady fleet (each tick frees what it makes) while the
    young generation grows: the keeper collects it by time, and freezes what survives instead of walking it
    again in middle and full collections."""
    generations: list[int] = []  # young collections seen
    enough = asyncio.Event()

    def seen(phase: str, info: dict[str, int]) -> None:
        if phase == "stop" and info["generation"] == 0:
            generations.append(0)
            if len(generations) >= 3 * FREEZE_EVERY:
                enough.set()

    keeper = CollectorKeeper(lambda: True, pace_s=0.001)
    gc.callbacks.append(seen)
    gc.freeze()
    task = asyncio.create_task(keeper.run())
    try:
        kept = [[i] for i in range(1000)]  # lists (always tracked): the ticks' survivors
        frozen_before = gc.get_freeze_count()
        async with asyncio.timeout(10):
            await enough.wait()
        assert gc.get_freeze_count() >= frozen_before + len(kept)
    finally:
        task.cancel()
        gc.callbacks.remove(seen)
        gc.unfreeze()
