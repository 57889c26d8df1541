"""Each injected fault ends in the documented error, and the session works again after reconnecting."""

from __future__ import annotations

import asyncio
import json
import time
import urllib.request
from collections.abc import AsyncIterator

import pytest

from edge.focas import items as it
from edge.focas.client import FocasClient
from edge.focas.errors import (
    AccessDenied,
    CncError,
    ConnectionLost,
    FocasTimeout,
    FunctionNotAvailable,
    ProtocolError,
)
from edge.sim.admin import AdminServer
from edge.sim.fleet import Fleet, Machine, MachineSpec
from tests.helpers import async_wait_for

pytestmark = pytest.mark.integration

TIMEOUT = 0.5


@pytest.fixture
async def fleet() -> AsyncIterator[Fleet]:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as running:
        yield running


@pytest.fixture
def machine(fleet: Fleet) -> Machine:
    return fleet[0]


def client(machine: Machine) -> FocasClient:
    return FocasClient("127.0.0.1", machine.port, timeout=TIMEOUT, connect_timeout=TIMEOUT)


async def works_after_reconnect(cnc: FocasClient, machine: Machine) -> None:
    await cnc.connect()
    assert await cnc.read_macros(500, 502) == machine.state.read_macros(500, 502)


async def test_latency_past_the_timeout_is_a_timeout(machine: Machine) -> None:
    cnc = client(machine)
    async with cnc:
        machine.faults.latency = 0.1
        started = time.monotonic()
        await cnc.read_status()  # slow but within the timeout
        assert time.monotonic() - started >= 0.1
        machine.faults.latency = TIMEOUT * 2
        with pytest.raises(FocasTimeout):
            await cnc.read_status()
        assert not cnc.connected
        machine.faults.latency = 0
        await works_after_reconnect(cnc, machine)


async def test_dropped_connection_is_connection_lost(machine: Machine) -> None:
    cnc = client(machine)
    async with cnc:
        machine.faults.drop_after = 2
        await cnc.read_status()  # the first request still answers
        with pytest.raises(ConnectionLost):
            await cnc.read_status()
        assert machine.faults.drop_after is None  # one-shot
        await works_after_reconnect(cnc, machine)


async def test_drop_now_cuts_open_sessions(machine: Machine) -> None:
    cnc = client(machine)
    async with cnc:
        await async_wait_for(lambda: machine.sessions == 1, message="the session to register")
        assert machine.drop_connections() == 1
        with pytest.raises(ConnectionLost):
            await cnc.read_status()
        await works_after_reconnect(cnc, machine)


async def test_refused_connections_are_connection_lost(machine: Machine) -> None:
    machine.faults.refuse = 2
    cnc = client(machine)
    for _ in range(2):
        with pytest.raises(ConnectionLost):
            await cnc.connect()
    assert machine.native.stats.refused == 2
    await works_after_reconnect(cnc, machine)
    await cnc.close()


async def test_refused_until_cleared_then_connect_with_retry(machine: Machine) -> None:
    machine.faults.refuse = -1
    cnc = FocasClient("127.0.0.1", machine.port, timeout=TIMEOUT, connect_timeout=TIMEOUT,
                      backoff_initial=0.01, backoff_max=0.05)
    task = asyncio.create_task(cnc.connect_with_retry(deadline=10))
    await async_wait_for(lambda: machine.native.stats.refused >= 3, message="three refused attempts")
    machine.faults.refuse = 0
    info = await asyncio.wait_for(task, 10)
    assert info.cnc_type == "30"
    await cnc.close()


async def test_hang_mid_frame_is_a_timeout(machine: Machine) -> None:
    cnc = client(machine)
    async with cnc:
        machine.faults.hang = 1
        started = time.monotonic()
        with pytest.raises(FocasTimeout):
            await cnc.batch([it.ReadMacros(500, 510), it.ReadStatus()])
        assert time.monotonic() - started < TIMEOUT * 4
        await works_after_reconnect(cnc, machine)
    await async_wait_for(lambda: machine.sessions == 0, message="the hung session to close")


async def test_garbage_is_a_protocol_error(machine: Machine) -> None:
    cnc = client(machine)
    async with cnc:
        machine.faults.garbage = 1
        with pytest.raises(ProtocolError, match="sync"):
            await cnc.read_status()
        await works_after_reconnect(cnc, machine)


async def test_injected_ew_code_fails_only_that_function(machine: Machine) -> None:
    cnc = client(machine)
    async with cnc:
        machine.faults.ew = {"read_macros": 6, 0x19: 17}
        macros, status, feed = await cnc.batch([it.ReadMacros(500, 500), it.ReadStatus(), it.ReadFeed()])
        assert isinstance(macros, FunctionNotAvailable) and macros.code == 6
        assert isinstance(status, AccessDenied) and status.code == 17
        assert isinstance(feed, float)
        machine.faults.update({"ew": {"read_pmc": 18}})
        with pytest.raises(CncError) as caught:
            await cnc.read_pmc("R", 0, 0)
        assert caught.value.code == 18 and caught.value.name == "EW_PMC"
        machine.faults.clear()
        await cnc.close()
        await works_after_reconnect(cnc, machine)
        await cnc.close()


async def test_session_limit(machine: Machine) -> None:
    machine.faults.max_sessions = 1
    first, second = client(machine), client(machine)
    async with first:
        with pytest.raises(ConnectionLost):
            await second.connect()
        assert (await first.read_status()).aut == 1
    await async_wait_for(lambda: machine.sessions == 0, message="the first session to close")
    await works_after_reconnect(second, machine)
    await second.close()


async def test_faults_through_the_admin_endpoint(fleet: Fleet, machine: Machine) -> None:
    """Another process drives faults and state over HTTP; the client sees them."""
    async with AdminServer(fleet) as admin:

        def post(path: str, body: dict[str, object]) -> dict[str, object]:
            request = urllib.request.Request(admin.url + path, data=json.dumps(body).encode(), method="POST",
                                             headers={"Content-Type": "application/json"})
            with urllib.request.urlopen(request, timeout=5) as response:
                return dict(json.load(response))

        cnc = client(machine)
        async with cnc:
            await asyncio.to_thread(post, "/machines/0/state",
                                    {"macros": {"505": 7.5}, "raise_alarm": {"number": 1010, "type": "EX"}})
            macros, alarms = await cnc.batch([it.ReadMacros(505, 505), it.ReadActiveAlarms()])
            assert macros == [7.5] and [a.number for a in alarms] == [1010]
            await asyncio.to_thread(post, "/machines/0/faults", {"garbage": 1})
            with pytest.raises(ProtocolError):
                await cnc.read_status()
            await works_after_reconnect(cnc, machine)
            reply = await asyncio.to_thread(post, "/machines/0/faults", {"drop_now": True})
            assert reply["dropped"] == 1
            with pytest.raises(ConnectionLost):
                await cnc.read_status()
