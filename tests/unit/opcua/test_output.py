"""OpcUaOutput's hand-over on the daemon's loop: a data batch is applied in the call when nothing is queued,
and queued behind whatever is (order kept); asyncua's own items are awaited by the drain."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from edge.opcua.output import OpcUaOutput
from edge.opcua.settings import OpcUaSettings
from edge.samples import MetricSpec, MetricType, Sample
from tests.helpers import async_wait_for

SPEC = MetricSpec("Macro/1", MetricType.DOUBLE)


class _Server:
    """What OpcUaOutput calls on GatewayServer, recorded; a birth waits until `release` is set."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.release = asyncio.Event()
        self.slow: list[Any] = []

    async def start(self) -> None:
        pass

    async def stop(self) -> None:
        pass

    async def machine_online(self, device_id: str, *_args: object) -> None:
        self.calls.append(("online", device_id))
        await self.release.wait()

    async def machine_data(self, device_id: str, samples: Any) -> None:
        self.calls.append(("queued data", samples[0].value))

    def show_data(self, device_id: str, samples: Any) -> list[Any]:
        self.calls.append(("data", samples[0].value))
        return self.slow


def _batch(value: float) -> list[Sample]:
    return [Sample(SPEC.name, value, SPEC.type, 1)]


@pytest.fixture
def output(tmp_path: Path) -> OpcUaOutput:
    made = OpcUaOutput(OpcUaSettings(state_dir=tmp_path))
    made.server = _Server()  # type: ignore[assignment]
    return made


async def test_data_is_applied_in_the_call_when_nothing_is_queued(output: OpcUaOutput) -> None:
    await output.start()
    try:
        await output.device_data("m1", _batch(1.0))
        assert output.server.calls == [("data", 1.0)]  # type: ignore[attr-defined]
        assert output.pending == 0
    finally:
        await output.stop()


async def test_data_waits_behind_a_birth_being_applied(output: OpcUaOutput) -> None:
    server: _Server = output.server  # type: ignore[assignment]
    await output.start()
    try:
        await output.device_online("m1", [SPEC], _batch(0.0))
        await async_wait_for(lambda: server.calls == [("online", "m1")], message="the birth being applied")
        await output.device_data("m1", _batch(1.0))  # the birth is out of the mailbox but not applied
        server.release.set()
        await output.device_data("m1", _batch(2.0))
        await async_wait_for(lambda: output.pending == 0 and len(server.calls) == 3, message="all applied")
        assert server.calls == [("online", "m1"), ("queued data", 1.0), ("queued data", 2.0)]
        await output.device_data("m1", _batch(3.0))
        assert server.calls[-1] == ("data", 3.0)
    finally:
        await output.stop()


async def test_items_on_asyncuas_path_are_awaited_by_the_drain(output: OpcUaOutput) -> None:
    server: _Server = output.server  # type: ignore[assignment]
    told: list[tuple[int, object]] = []

    async def callback(handle: int, value: object) -> None:
        told.append((handle, value))

    server.slow = [(5, callback, "value")]
    await output.start()
    try:
        await output.device_data("m1", _batch(1.0))
        await async_wait_for(lambda: told == [(5, "value")], message="the filtered item told")
    finally:
        await output.stop()
