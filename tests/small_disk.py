"""A small real filesystem for full-disk drills: a tmpfs of a given size mounted on a temporary directory.

Needs root (mount). Where the mount is impossible the test is skipped with the reason; the mount is always
undone, even when the test fails.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


@contextlib.contextmanager
def small_disk(where: Path, size: str = "1m") -> Iterator[Path]:
    """Mount a `size` tmpfs on `where` (created) for the block; skip the test if it cannot be mounted."""
    if os.geteuid() != 0:
        pytest.skip("a full-disk drill needs a small filesystem: mounting a tmpfs needs root")
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size},mode=0700", "tmpfs", str(where)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"a full-disk drill needs a small filesystem: mount -t tmpfs failed: {done.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True, check=False)


def fill(directory: Path, name: str = "filler") -> Path:
    """Take every free byte of the filesystem under `directory` (ENOSPC stops the write)."""
    path = directory / name
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    try:
        with contextlib.suppress(OSError):
            while os.write(fd, b"\0" * 4096):
                pass
        with contextlib.suppress(OSError):
            while os.write(fd, b"\0"):  # the last partial block
                pass
    finally:
        os.close(fd)
    return path


def disk_use(*paths: Path) -> int:
    """Bytes these files take (missing files count 0)."""
    return sum(p.stat().st_size for p in paths if p.exists())
