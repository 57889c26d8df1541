"""The daemon's loop given a turn whenever a long piece of OPC UA work has held it for SLICE_S.

A request of thousands of operations (browse 500 folders, read or subscribe 10,000 values) is served a few
operations at a time; between two slices the poll loop and MQTT run. Slices are measured in time, not
counted in operations: an operation's cost varies tenfold between requests and between hosts (a Raspberry
Pi, a shared VM), and what the poll loop feels is the time it waits.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Sequence
from typing import Any, TypeVar

T = TypeVar("T")

# the longest the loop is held between two turns (about: it is checked every STEP operations). A poll tick
# takes a few loop turns between its request and its samples reaching MQTT, each one waiting for a slice;
# but each turn given also waits for a whole loop iteration of the daemon's other work (tens of ms at 100
# machines on a busy host), so slices much shorter stretch a large request past a client's timeout
# (node-opcua's is 15 s: 4 ms slices and 40-item create chunks made a 10,000-item burst fail under load)
SLICE_S = 0.010
STEP = 8  # operations between two looks at the clock


class Turns:
    """Counts the time since the loop last had a turn; `give` yields once SLICE_S has passed."""

    def __init__(self) -> None:
        self._since = time.perf_counter()
        self.given = 0  # turns given so far (tests read it)

    async def give(self) -> None:
        """A loop turn, if the work since the last one has held the loop SLICE_S."""
        if time.perf_counter() - self._since >= SLICE_S:
            await asyncio.sleep(0)
            self.given += 1
            self._since = time.perf_counter()


async def slices(items: Sequence[T], turns: Turns | None = None) -> AsyncIterator[list[T]]:
    """`items` STEP at a time, the loop given a turn between two steps whenever SLICE_S has passed. A sequence
    decoded on demand (edge.opcua.pending_items) is decoded a step at a time too (`take`)."""
    turns = turns or Turns()
    take: Any = getattr(items, "take", None)
    for start in range(0, len(items), STEP):
        if start:
            await turns.give()
        yield take(STEP) if take is not None else list(items[start:start + STEP])
