"""Interop with an independent implementation: the published pyfocas 0.1.1 talks to our simulated CNC.

pyfocas is a blocking socket client, so the fleet runs on its own loop in a background thread.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from edge.sim.fleet import Fleet, FleetThread, MachineSpec
from edge.sim.profiles import PROFILES

pyfocas_protocol = pytest.importorskip("pyfocas.protocol.protocol")

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def fleet() -> Iterator[Fleet]:
    specs = [MachineSpec(profile=name) for name in sorted(PROFILES)]
    with FleetThread(Fleet(specs, base_port=0)) as running:
        yield running


@pytest.fixture(params=range(len(PROFILES)), ids=sorted(PROFILES))
def connected(request: pytest.FixtureRequest, fleet: Fleet) -> Iterator[tuple[object, int]]:
    index = int(request.param)
    focas = pyfocas_protocol.FOCAS("127.0.0.1", fleet[index].port)
    assert focas.connect() is True
    try:
        yield focas, index
    finally:
        assert focas.socket is not None
        focas.socket.close()


def test_pyfocas_reads_sysinfo_status_and_macro_502(connected: tuple[object, int], fleet: Fleet) -> None:
    focas, index = connected
    state = fleet[index].state
    info = focas.get_sys_info()  # type: ignore[attr-defined]
    expected = state.sysinfo()
    assert (info.max_axis, info.cnc_type, info.series, info.version) == (
        expected.max_axis, expected.cnc_type.strip(), expected.series, expected.version)
    status = focas.get_status_info()  # type: ignore[attr-defined]
    assert status.aut == 1 and status.run in (0, 3)
    assert focas.read_macro(502) == {502: state.read_macro(502)}  # type: ignore[attr-defined]
    assert focas.read_macro(500, 503) == dict(zip(range(500, 504), state.read_macros(500, 503), strict=True))  # type: ignore[attr-defined]


def test_pyfocas_double_write_reaches_the_machine(connected: tuple[object, int], fleet: Fleet) -> None:
    focas, index = connected
    state = fleet[index].state
    value = 1234.5678 + index
    reply = focas.write_macro_double(640, value)  # type: ignore[attr-defined]
    assert reply.packet_type == 0x2102
    (subpacket,) = reply.data
    assert subpacket[:6] == b"\x00\x01\x00\x01\x00\xa8" and subpacket[6:8] == b"\x00\x00"  # echo, rc 0
    assert state.read_macro(640) == value
    last = state.writes("macro:640")[-1]
    assert (last.protocol, last.new) == ("native", value)
    assert focas.read_macro(640) == {640: value}  # type: ignore[attr-defined]
