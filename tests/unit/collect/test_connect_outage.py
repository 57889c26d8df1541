"""A machine that stays switched off does not flood the journal: the poller logs the first failed connect at
WARNING, the retries at DEBUG, and one INFO line with the count when the machine answers again."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import pytest

from bench.floor import DroppingSink
from edge.collect.poller import MachinePoller
from edge.config import parse_config
from edge.focas import items as it
from edge.focas.errors import ConnectionLost
from edge.focas.model import Capabilities, SysInfo
from edge.focas.session import CncSession, ItemResult
from edge.service.settings import machine_settings

CONFIG = """
mqtt: {host: 127.0.0.1, sparkplug: {group_id: g, edge_node_id: n}}
machines:
  - id: m1
    host: 127.0.0.1
    timeouts: {backoff_initial_s: 0.001, backoff_max_s: 0.002}
"""
SYSINFO = SysInfo(addinfo=0, max_axis=8, cnc_type="31", mt_type=" M", series="G421", version="23.0", axes="03")


class SwitchedOffSession(CncSession):
    """Refuses `refusals` connects (a control that is off), then answers."""

    transport = "scripted"

    def __init__(self, refusals: int) -> None:
        super().__init__()
        self.refusals = refusals

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(self.transport, frozenset())

    async def _open(self) -> SysInfo:
        if self.refusals:
            self.refusals -= 1
            raise ConnectionLost("connect: [Errno 111] Connection refused")
        return SYSINFO

    async def _close(self) -> None:
        pass

    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:  # pragma: no cover - not polled
        raise AssertionError("not used")

    async def _write_macro(self, number: int, value: float) -> None:  # pragma: no cover
        raise AssertionError("not used")

    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:  # pragma: no cover
        raise AssertionError("not used")

    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None:  # pragma: no cover
        raise AssertionError("not used")


async def test_a_run_of_failed_connects_is_one_warning_then_one_line_when_connected_again(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="edge.collect.poller")
    config = parse_config(CONFIG)
    session = SwitchedOffSession(refusals=40)
    poller = MachinePoller(machine_settings(config, config.machines[0]), DroppingSink(), tmp_path,
                           session_factory=lambda _machine: session)
    await poller._connect()
    records = [r for r in caplog.records if r.name == "edge.collect.poller"]
    warnings = [r.getMessage() for r in records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith("connect failed machine=m1 error=connect: [Errno 111] Connection refused")
    assert sum(r.levelno == logging.DEBUG and "connect failed machine=m1 attempt=" in r.getMessage()
               for r in records) == 39
    again = [r.getMessage() for r in records if r.levelno == logging.INFO and "connected again" in r.getMessage()]
    assert len(again) == 1 and again[0].startswith("machine=m1 connected again after 0 s, 40 failed attempts")
    assert poller.last_error.startswith("connect failed: connect: [Errno 111]")  # the status page still says why
