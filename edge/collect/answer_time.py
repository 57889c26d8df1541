"""When a CNC answered a request, as the poller stamps the tick's values.

The CNC answered somewhere between the request's send and the moment the poller handled its answer. The
middle of that span is right when both halves are the network's. At 1,000 machines the second half also
holds the gateway's own delay: the answer waits while the event loop serves the other machines of the
same grid slot, or a garbage collection holds the loop. Stamping the middle then made the stamps of those
ticks late by half that delay (issue 25: stamp error p99 216 ms at 1,000 machines, 13 ms at 100), while
issue 24 wants a stamp to say when the CNC's values were true, however late the gateway got to them.

The machine's usual round trip (the least of its last few: a network and a CNC that answered without
waiting on the gateway) says how long the request's own part takes, so the answer is taken to have come
half a usual round trip after the send, never later than the middle. The clock tracker still gets the
whole span as its reading's uncertainty (edge.collect.clock): its bounds stay honest either way.
"""

from __future__ import annotations

from collections import deque

WINDOW = 16  # round trips remembered: a CNC whose round trip really grew is followed within this many ticks


class AnswerTime:
    """One machine's recent round trips; `half_rtt` is the part of a round trip before the CNC answered."""

    def __init__(self, window: int = WINDOW) -> None:
        self._recent: deque[float] = deque(maxlen=window)

    def half_rtt(self, rtt_s: float) -> float:
        """Seconds from the send to the CNC's answer for a request that took `rtt_s` to be handled."""
        recent = self._recent
        recent.append(rtt_s)
        return min(recent) / 2

    def reset(self) -> None:
        """A new session (another route, maybe another CNC): its round trips start afresh."""
        self._recent.clear()
