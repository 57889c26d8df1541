"""Give the C heap's free pages back to the system after start-up, reloads and a spool replay (glibc's
malloc_trim).

Start-up allocates far more than it keeps: the config's parse, each machine's static reads, plans and
births. Python's own allocator unmaps an arena once it is empty, but objects over 512 bytes (dict tables,
large lists, byte strings) come from malloc, and glibc returns freed memory in the middle of its heap only
when asked. `trim()` asks; where there is no glibc (musl, macOS) it does nothing.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    try:
        function = ctypes.CDLL(None).malloc_trim  # the process's own symbols: libc's, without a search
    except (OSError, AttributeError):  # not glibc
        return None
    function.argtypes = [ctypes.c_size_t]
    function.restype = ctypes.c_int
    return function


def trim() -> bool:
    """Release the C heap's free pages; True if glibc had any to give back."""
    function = _malloc_trim()
    return function is not None and bool(function(0))
