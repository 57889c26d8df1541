"""The open-file limit a fleet needs, and raising the soft limit to it where the process may.

Each machine holds one TCP socket to its CNC (native or packed transport), plus one to the FOCAS library
host when it names `fwlib_host`; a further path of a machine is its own session with its own socket. Beside
those the process keeps a fixed set: stdio, the event loop's epoll and self-pipe, each MQTT connection
and paho's wake-up socket pair, the spool (database, WAL, shared memory, headroom file), the state_dir lock,
the status and OPC UA listeners and their clients, the executor threads' files. A shell's soft limit is
often 1,024, and at 1,000 machines the gateway holds ~1,010 descriptors (`python -m bench fleet`), so
`focas-edge run` raises its soft limit to what the fleet needs (up to the hard limit). Under systemd the unit
sets LimitNOFILE= (and its system-call filter refuses setrlimit), see systemd/focas-edge.service.
"""

from __future__ import annotations

import logging
import resource
from collections.abc import Callable

log = logging.getLogger(__name__)

FIXED_FDS = 128  # what the process holds whatever the fleet (bench fleet: 111 descriptors at 100 machines, 11 fixed)
HEADROOM = 2  # reconnects briefly hold a closing socket beside its successor; status and OPC UA clients come and go

Limits = tuple[int, int]


def fds_needed(sessions: int, library_sessions: int) -> int:
    """Descriptors a fleet of `sessions` CNC sessions, `library_sessions` of them also routed to a library host,
    may hold at once, with headroom."""
    return FIXED_FDS + HEADROOM * (sessions + library_sessions)


def ensure_fd_limit(needed: int, get: Callable[[int], Limits] = resource.getrlimit,
                    set_: Callable[[int, Limits], None] = resource.setrlimit) -> int:
    """Raise the soft RLIMIT_NOFILE to `needed` (capped by the hard limit); the soft limit in force after.

    A limit that stays short is a WARNING naming the setting to change, not a refusal: the machines beyond it
    fail to connect with EMFILE, each with its own error, and the rest are polled.
    """
    soft, hard = get(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < needed:
        target = needed if hard == resource.RLIM_INFINITY else min(needed, hard)
        try:
            set_(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (OSError, ValueError) as exc:  # a system-call filter (systemd's ~@resources) refuses it
            log.debug("open-file limit not raised error=%r", exc)
    if soft != resource.RLIM_INFINITY and soft < needed:
        log.warning("open-file limit %d is below the %d descriptors this fleet may need: raise LimitNOFILE= in the "
                    "unit (or ulimit -n) to at least %d", soft, needed, needed)
    return soft
