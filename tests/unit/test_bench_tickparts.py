"""bench.tickparts times a replayed tick by layer (no speed assertions): every layer is reached, the timers are
put back afterwards, and the tick's own loop is what is left of it."""

from __future__ import annotations

import asyncio

from bench import tickparts, tickreplay
from edge.collect.poller import MachinePoller


def test_every_layer_of_a_replayed_tick_is_timed_and_the_originals_restored() -> None:
    recording = asyncio.run(tickreplay._record(0.1, 1.5))
    before = MachinePoller._tick
    parts = tickparts.run(recording, 2)
    assert MachinePoller._tick is before
    tick_us, tick_calls = parts["tick, in all"]
    assert tick_calls == 1.0 and tick_us > 0
    assert parts["client batch (split and decode)"][1] == 1.0 and parts["  of which the answer split"][1] >= 1.0
    assert parts["change detection (report)"][1] > 0 and parts["DATA encoding (device_data)"][1] > 0
    own, _ = parts["tick's own loop (_tick less its timed callees)"]
    assert 0 < own < tick_us
