"""How many paths a control has (a twin-turret lathe: 2), found by asking each path for its status.

No public wire code of cnc_getpath is known; every request subpacket names its path, and a control
answers a path it does not have with EW_PATH (fwlib32.h: "path number error"). So statinfo is asked on
paths 1..MAX_PATHS in one request and the paths before the first refused one are the control's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from edge.focas import items as it
from edge.focas.errors import FocasError

if TYPE_CHECKING:  # a type only: targets (sans-IO) imports MAX_PATHS and must not pull in the asyncio session
    from edge.focas.session import CncSession

MAX_PATHS = 10  # the most paths a 30i-B series control offers


async def path_count(session: CncSession, max_paths: int = MAX_PATHS) -> int:
    """The number of paths answering (1 when the transport cannot ask another path)."""
    if not session.capabilities.can("ReadPathStatus"):
        return 1
    results = await session.batch([it.ReadPathStatus(path) for path in range(1, max_paths + 1)])
    count = 0
    for result in results:
        if isinstance(result, FocasError):
            break
        count += 1
    return max(1, count)
