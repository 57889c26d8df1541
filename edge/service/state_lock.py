"""One daemon per state_dir: an advisory lock on `<state_dir>/focas-edge.lock`, held for the daemon's life.

Two daemons on one state_dir would share the spool and the bdSeq file (the spool depth goes negative,
hosts see a bdSeq from another session). flock(2) is released by the kernel however the holder ends
(kill -9, a power cut), so a lock file left behind never blocks a start; it keeps the last holder's PID,
which is what the refusal names. The lock is taken before anything else in state_dir is opened.

`holder()` answers for `check-config` without creating anything: it probes the lock for a moment, so a
daemon starting at that instant retries for CONTENDED_RETRY_S before it concludes the lock is held.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import time
from dataclasses import dataclass
from pathlib import Path

from edge import ConfigError

LOCK_FILE = "focas-edge.lock"
SERVICE_UNIT = "focas-edge.service"
CONTENDED_RETRY_S = 0.5


@dataclass(frozen=True)
class Holder:
    """The process holding a state_dir's lock, as far as can be told."""

    pid: int | None
    unit: str | None  # the systemd unit it runs in, when /proc says

    @property
    def is_service(self) -> bool:
        return self.unit == SERVICE_UNIT


def held_message(state_dir: Path, holder: Holder) -> str:
    """The one line both `run` and `check-config` print for a state_dir in use."""
    who = f"PID {holder.pid}" if holder.pid is not None else "a process whose PID is unknown"
    if holder.unit:
        who += f", {holder.unit}"
    stop = "systemctl stop focas-edge" if holder.is_service else f"kill {holder.pid}" if holder.pid else "stop it"
    return (f"state_dir: {state_dir} is in use by another focas-edge ({who}; lock {state_dir / LOCK_FILE}): "
            f"two gateways on one state_dir would share its spool and bdSeq; stop that one first ({stop}) "
            f"or give this one its own state_dir")


class StateDirLock:
    """The held lock; release() (or process exit) gives it up."""

    def __init__(self, state_dir: Path, fd: int) -> None:
        self.state_dir = state_dir
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, state_dir: Path) -> StateDirLock:
        """Take the lock (creating state_dir and the lock file if missing) and write our PID into it.

        ConfigError (one line) when another process holds it; PermissionError when the lock file cannot be
        opened for writing (a file left by another user: the caller names the fix).
        """
        state_dir.mkdir(parents=True, exist_ok=True)
        path = state_dir / LOCK_FILE
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
        try:
            if not _lock(fd, fcntl.LOCK_EX, CONTENDED_RETRY_S):
                raise ConfigError([held_message(state_dir, _describe(fd))])
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except BaseException:
            os.close(fd)
            raise
        return cls(state_dir, fd)

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # closing the only descriptor drops the flock


def holder(state_dir: Path) -> Holder | None:
    """Who holds state_dir's lock, or None when nobody does (or there is no lock file yet)."""
    try:
        fd = os.open(state_dir / LOCK_FILE, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None  # no lock file: nothing ever ran there; unreadable: the state-file check names it
    try:
        if _lock(fd, fcntl.LOCK_SH, 0.0):
            return None
        return _describe(fd)
    finally:
        os.close(fd)  # also drops the shared lock taken by the probe


def _lock(fd: int, mode: int, retry_s: float) -> bool:
    """flock without blocking; retried for `retry_s` (a check-config probing at the same instant)."""
    deadline = time.monotonic() + retry_s
    while True:
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
            return True
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)


def _describe(fd: int) -> Holder:
    """The PID the holder wrote, and its systemd unit (from /proc/PID/cgroup, when readable)."""
    with contextlib.suppress(OSError, ValueError):
        pid = int(os.pread(fd, 32, 0).decode().strip())
        return Holder(pid, _unit_of(pid))
    return Holder(None, None)


def _unit_of(pid: int) -> str | None:
    with contextlib.suppress(OSError):
        for line in Path(f"/proc/{pid}/cgroup").read_text().splitlines():
            name = line.rpartition("/")[2]
            if name.endswith(".service"):
                return name
    return None
