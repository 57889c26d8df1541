"""How many paths the control has, asked once per session by a machine's path-1 poller.

The count is published as `Device/Paths` and compared with the configured `paths: N`: a control with more
paths than configured says so once (naming the key to add), one with fewer says which devices stay offline.
A path device whose path the control lacks fails its connect with EW_PATH; `connect_error` turns that
into a message naming the config key, since "EW_PATH (11)" alone does not tell an engineer what to change.
"""

from __future__ import annotations

import logging

from edge.collect.settings import MachineSettings
from edge.focas.errors import EW_PATH, CncError
from edge.focas.paths import path_count
from edge.focas.session import CncSession
from edge.samples import MetricSpec, MetricType

log = logging.getLogger(__name__)

PATH_COUNT = MetricSpec("Device/Paths", MetricType.INT32,
                        description="CNC paths the control answers (asked once per session)")


class PathCheck:
    """Asks a machine's path count and compares it with the config; says each mismatch once per run."""

    def __init__(self, machine: MachineSettings) -> None:
        self.machine = machine
        self._said: int | None = None  # the count last warned about

    async def count(self, session: CncSession) -> int | None:
        """The control's path count; None where it is not asked (a path device, a transport without it)."""
        if self.machine.path != 1 or not session.capabilities.can("ReadPathStatus"):
            return None
        count = await path_count(session)
        self._compare(count)
        return count

    def _compare(self, count: int) -> None:
        configured = self.machine.paths
        if count == configured or count == self._said:
            return
        self._said = count
        if count > configured:
            log.warning("machine=%s the control has %d paths, %d configured: add `paths: %d` to machine %s "
                        "to publish paths %d..%d", self.machine.id, count, configured, count, self.machine.id,
                        configured + 1, count)
        else:
            offline = ", ".join(self.machine.path_devices[count:])
            log.warning("machine=%s the control has %d path(s), %d configured (`paths: %d`): %s stay(s) "
                        "offline; set `paths: %d`", self.machine.id, count, configured, configured, offline, count)


def connect_error(machine: MachineSettings, error: BaseException | None) -> str:
    """Why a connect failed: the error, and for a path the control lacks which config key to change."""
    if isinstance(error, CncError) and error.code == EW_PATH and machine.path != 1:
        return (f"path {machine.path} is not on this control ({error}); the machine's `paths:` names more "
                "paths than the control has (`focas-edge probe` prints the count)")
    return str(error)
