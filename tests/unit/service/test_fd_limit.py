"""The open-file limit: what a fleet needs, raised where allowed, and the shipped units fit 2,000 machines."""

from __future__ import annotations

import logging
import re
import resource
from pathlib import Path

import pytest

from edge.service.fd_limit import ensure_fd_limit, fds_needed

REPO = Path(__file__).resolve().parents[3]
HARD = 524288


def test_the_soft_limit_is_raised_to_what_the_fleet_needs_and_no_further() -> None:
    calls: list[tuple[int, int]] = []
    soft = ensure_fd_limit(fds_needed(2000, 0), lambda _: (1024, HARD), lambda _, limits: calls.append(limits))
    assert calls == [(fds_needed(2000, 0), HARD)] and soft == fds_needed(2000, 0) > 2000


def test_a_limit_high_enough_is_left_alone() -> None:
    def refuse(*_: object) -> None:
        raise AssertionError("setrlimit called")
    assert ensure_fd_limit(500, lambda _: (1024, HARD), refuse) == 1024


def test_a_limit_that_cannot_be_raised_is_a_warning_naming_the_setting(caplog: pytest.LogCaptureFixture) -> None:
    def filtered(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")  # systemd's SystemCallFilter=~@resources
    with caplog.at_level(logging.WARNING):
        assert ensure_fd_limit(fds_needed(2000, 2000), lambda _: (1024, 1024), filtered) == 1024
    assert "LimitNOFILE" in caplog.text and str(fds_needed(2000, 2000)) in caplog.text


def test_the_hard_limit_caps_the_raise() -> None:
    calls: list[tuple[int, int]] = []
    assert ensure_fd_limit(8000, lambda _: (1024, 4096), lambda _, limits: calls.append(limits)) == 4096
    assert calls == [(4096, 4096)]


def test_this_process_can_be_raised_for_real() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    try:
        wanted = soft + 1 if hard == resource.RLIM_INFINITY or soft < hard else soft
        assert ensure_fd_limit(wanted) >= wanted
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


@pytest.mark.parametrize(("unit", "per_machine"), [("focas-edge.service", 2), ("focas-edge-fwlib-host.service", 2)])
def test_the_shipped_units_fit_2000_machines_routed_to_a_library_host(unit: str, per_machine: int) -> None:
    text = (REPO / "systemd" / unit).read_text()
    (limit,) = re.findall(r"^LimitNOFILE=(\d+)$", text, re.MULTILINE)
    assert int(limit) >= fds_needed(2000, 2000) >= 2000 * per_machine
