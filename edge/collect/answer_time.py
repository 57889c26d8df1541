"""When a CNC answered a request, as the poller stamps the tick's values.

The CNC answered somewhere between the request's send and the moment the poller handled its answer. The
middle of that span is right when both halves are the network's. At 1,000 machines the second half also
holds the gateway's own delay: the answer waits while the event loop serves the other machines of the
same grid slot, or a garbage collection holds the loop. Stamping the middle then made the stamps of those
ticks late by half that delay (issue 25: stamp error p99 216 ms at 1,000 machines, 13 ms at 100), while
issue 24 wants a stamp to say when the CNC's values were true, however late the gateway got to them.

The machine's usual round trip says how long the request's own part takes (the network and a CNC that
answered without waiting on the gateway), so the answer is taken to have come half a usual round trip
after the send, never later than the middle. "Usual" is a floor that drops at once to a quicker round trip
and rises a sixteenth of the way towards a slower one per tick: one late answer barely moves it, a CNC
whose round trip really grew is followed within a few dozen ticks. One float per machine (a window of
recent round trips would cost ~1 kB a machine, which 1,000 machines' memory budget does not have).
The clock tracker still gets the whole span as its reading's uncertainty (edge.collect.clock): its
bounds stay honest either way.
"""

from __future__ import annotations

RISE = 1 / 16  # how far towards a slower round trip the floor moves per tick


class AnswerTime:
    """One machine's usual round trip; `half_rtt` is the part of a round trip before the CNC answered."""

    __slots__ = ("_floor",)

    def __init__(self) -> None:
        self._floor = float("inf")

    def half_rtt(self, rtt_s: float) -> float:
        """Seconds from the send to the CNC's answer for a request that took `rtt_s` to be handled."""
        floor = self._floor
        if rtt_s <= floor:
            self._floor = rtt_s
            return rtt_s / 2
        self._floor = floor + (rtt_s - floor) * RISE
        return floor / 2

    @property
    def usual_s(self) -> float:
        """The machine's usual round trip (inf before the first): the clock probes compare it over time."""
        return self._floor

    def reset(self) -> None:
        """A new session (another route, maybe another CNC): its round trips start afresh."""
        self._floor = float("inf")
