"""The packed transport against the simulator over real sockets (TCP and Unix), same state as native."""

from __future__ import annotations

import asyncio
import random
import struct
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from edge.focas import items as it
from edge.focas import packed as pk
from edge.focas.errors import (
    AccessDenied,
    ConnectionLost,
    FocasError,
    FunctionNotAvailable,
    NotSupported,
    OutOfRange,
    ProtocolError,
)
from edge.focas.model import ParamType, PmcType
from edge.focas.packed import endpoint as packed_endpoint
from edge.focas.packed.client import PackedClient
from edge.focas.packed.frame import FrameDecoder, PackedFrame
from edge.sim.packed_server import PackedServer, start_packed_server
from edge.sim.state import MachineState
from tests.helpers import async_wait_for

pytestmark = pytest.mark.integration


@pytest.fixture
def state() -> MachineState:
    return MachineState("30i", name="packed-test")


@pytest.fixture
async def server(state: MachineState) -> AsyncIterator[PackedServer]:
    handle = await start_packed_server(state, "127.0.0.1", 0)
    try:
        yield handle
    finally:
        await handle.close()


@pytest.fixture
async def client(server: PackedServer) -> AsyncIterator[PackedClient]:
    cnc = PackedClient(server.address, timeout=5.0, connect_timeout=5.0)
    await cnc.connect()
    try:
        yield cnc
    finally:
        await cnc.close()


async def raw_call(server: PackedServer, command: int, payload: bytes, seq: int = 1) -> PackedFrame:
    """One request over a plain socket, bypassing the client's encoders and chunking."""
    reader, writer = await asyncio.open_connection(server.host, server.port)
    try:
        writer.write(PackedFrame(command, seq, payload).encode())
        await writer.drain()
        decoder = FrameDecoder()
        while True:
            data = await asyncio.wait_for(reader.read(65536), 5.0)
            assert data, "server closed without answering"
            frames = decoder.feed(data)
            if frames:
                return frames[0]
    finally:
        writer.close()
        await writer.wait_closed()


# ---- connection, addressing ----------------------------------------------------------------------------
async def test_connect_reads_sysinfo_over_tcp(client: PackedClient, state: MachineState) -> None:
    assert client.sysinfo == state.sysinfo()
    assert client.transport == "packed"
    assert client.capabilities.can("ReadAlarmHistory") and client.capabilities.can("write_param")
    assert not client.capabilities.can("ReadSpindleLoad")


@pytest.mark.parametrize("form", ["tcp:{host}:{port}", "{host}:{port}"])
async def test_tcp_address_forms(server: PackedServer, form: str) -> None:
    async with PackedClient(form.format(host=server.host, port=server.port)) as cnc:
        assert (await cnc.read_status()).aut == server.state.status().aut


async def test_unix_socket_transport(state: MachineState, tmp_path: Path) -> None:
    path = str(tmp_path / "cnc.sock")
    handle = await start_packed_server(state, unix_path=path)
    try:
        assert handle.address == f"unix:{path}"
        async with PackedClient(f"unix:{path}") as cnc:
            assert cnc.sysinfo == state.sysinfo()
            await cnc.write_macro(510, 2.5)
            assert await cnc.read_macros(510) == [2.5]
    finally:
        await handle.close()
    assert not await asyncio.to_thread(Path(path).exists)


async def test_connect_to_nothing_is_connection_lost(tmp_path: Path) -> None:
    with pytest.raises(ConnectionLost):
        await PackedClient(f"unix:{tmp_path / 'absent.sock'}", connect_timeout=2.0).connect()


async def test_server_close_ends_open_sessions(state: MachineState) -> None:
    handle = await start_packed_server(state)
    cnc = PackedClient(handle.address, timeout=2.0)
    await cnc.connect()
    await async_wait_for(lambda: handle.connections == 1, message="one open session")
    await handle.close()
    with pytest.raises(ConnectionLost):
        await cnc.read_status()
    await cnc.close()


# ---- batches -------------------------------------------------------------------------------------------
async def test_batch_returns_one_result_per_item_with_per_item_errors(
        client: PackedClient, state: MachineState) -> None:
    items: list[it.ReadItem] = [
        it.ReadStatus(), it.ReadMacros(500, 502), it.ReadMacros(5000, 5000), it.ReadSpindleLoad(),
        it.ReadParams(6711, 6711), it.ReadPmc("D", 2204, 2205, PmcType.WORD), it.ReadPmc("M", 0, 0),
        it.ReadAlarmHistory(5), it.ReadAxisNames(), it.ReadPositions("nowhere"), it.ReadClock(),
    ]
    results = await client.batch(items)
    assert len(results) == len(items)
    status, macros, bad_macro, load, params, pmc_word, bad_area, history, names, bad_kind, clock = results
    assert status.aut == state.status().aut
    assert macros == state.read_macros(500, 502)
    assert isinstance(bad_macro, OutOfRange) and bad_macro.name == "EW_NUMBER"
    assert isinstance(load, NotSupported)
    assert params[0].number == 6711 and params[0].value == state.part_count
    assert pmc_word == [600]  # D2204 as a word, same value the native protocol reads
    assert isinstance(bad_area, OutOfRange)
    assert history == state.alarm_history(5)
    assert names == state.axis_names()
    assert isinstance(bad_kind, OutOfRange)
    assert abs((clock - state.clock()).total_seconds()) < 5


async def test_every_supported_read_answers(client: PackedClient) -> None:
    items: list[it.ReadItem] = [
        it.ReadSysInfo(), it.ReadStatus(), it.ReadAlarmStatus(), it.ReadActiveAlarms(),
        it.ReadProgramNumber(), it.ReadSequenceNumber(), it.ReadFeed(), it.ReadSpindleSpeed(),
        it.ReadPositions("machine"),
        it.ReadAxisNames(), it.ReadParams(1, 9999), it.ReadDiag(980, 982, 1), it.ReadMacros(100, 199),
        it.ReadPmc("G", 0, 31), it.ReadClock(), it.ReadTimer(1), it.ReadAlarmHistory(250),
    ]
    assert {i.operation for i in items} <= client.capabilities.supported
    results = await client.batch(items)
    errors = [(item, r) for item, r in zip(items, results, strict=True) if isinstance(r, FocasError)]
    assert errors == []


async def test_active_alarms_and_history_follow_the_state(client: PackedClient, state: MachineState) -> None:
    state.raise_alarm(3001, 15, 0, "SPINDLE COOLANT")
    active, status, history = await client.batch(
        [it.ReadActiveAlarms(), it.ReadAlarmStatus(), it.ReadAlarmHistory(1)])
    assert [a.number for a in active] == [3001]
    assert status == 1 << 15
    assert history[0].alm_no == 3001 and history[0].message == "SPINDLE COOLANT"
    assert history[0].occurred.tzinfo is not None


async def test_unknown_command_answers_ew_func(server: PackedServer) -> None:
    reply = await raw_call(server, 0x7ABC, b"", seq=42)
    assert (reply.command, reply.seq, reply.payload) == (0x7ABC, 42, struct.pack("<h", 1))


# ---- PMC writes: chunking and the 32-byte ceiling ----------------------------------------------------------
async def test_a_70_byte_pmc_write_is_three_calls_of_32_32_6(
        client: PackedClient, server: PackedServer, state: MachineState) -> None:
    data = bytes(random.Random(7).randrange(256) for _ in range(70))
    await client.write_pmc("R", 1000, data)
    calls = [pk.decode_pmc_range(r.payload, True) for r in server.requests_for(pk.Command.WRPMCRNG)]
    assert [(c.start, c.end, len(c.data)) for c in calls] == [
        (1000, 1031, 32), (1032, 1063, 32), (1064, 1069, 6)]
    assert b"".join(c.data for c in calls) == data
    assert state.read_pmc_bytes("R", 1000, 1069) == data
    assert [w.target for w in state.writes("pmc:R1")] == [
        "pmc:R1000-R1031", "pmc:R1032-R1063", "pmc:R1064-R1069"]
    assert await client.read_pmc("R", 1000, 1069) == list(data)


async def test_a_33_byte_raw_pmc_call_gets_ew_length(server: PackedServer, state: MachineState) -> None:
    before = state.read_pmc_bytes("R", 0, 32)
    payload = pk.encode_pmc_range(pk.PmcRange("R", 0, 0, 32, bytes(range(1, 34))))
    reply = await raw_call(server, pk.Command.WRPMCRNG, payload)
    assert reply.payload == struct.pack("<h", 2)  # EW_LENGTH
    assert state.read_pmc_bytes("R", 0, 32) == before
    exactly_32 = pk.encode_pmc_range(pk.PmcRange("R", 0, 0, 31, bytes(range(1, 33))))
    assert (await raw_call(server, pk.Command.WRPMCRNG, exactly_32)).payload == struct.pack("<h", 0)


async def test_pmc_write_outside_the_area_is_ew_number(client: PackedClient, state: MachineState) -> None:
    size = state.pmc_size("R")
    with pytest.raises(OutOfRange) as info:
        await client.write_pmc("R", size - 2, b"\x01\x02\x03")
    assert info.value.name == "EW_NUMBER"


async def test_eight_tasks_setting_bits_0_to_7_at_once_leave_all_eight_set(
        client: PackedClient, state: MachineState) -> None:
    state.write_pmc("R", 200, b"\x00", protocol="test")
    await asyncio.gather(*(client.write_pmc_bit("R", 200, bit, True) for bit in range(8)))
    assert state.read_pmc_bytes("R", 200, 200) == b"\xff"
    assert len(state.writes("pmc:R200")) == 1 + 8


@pytest.mark.parametrize("seed", range(5))
async def test_random_concurrent_sets_and_clears_end_in_the_implied_byte(
        client: PackedClient, state: MachineState, seed: int) -> None:
    rng = random.Random(seed)
    initial = rng.randrange(256)
    state.write_pmc("R", 300, bytes([initial]), protocol="test")
    # each touched bit is driven one way only (set or clear), several times, interleaved with the
    # other bits' operations: the end byte is then fixed whatever order the tasks run in, and any
    # lost read-modify-write shows as a wrong bit
    plan = {bit: rng.choice([True, False]) for bit in rng.sample(range(8), rng.randint(3, 8))}
    operations = [(bit, value) for bit, value in plan.items() for _ in range(rng.randint(1, 4))]
    rng.shuffle(operations)
    await asyncio.gather(*(client.write_pmc_bit("R", 300, bit, value) for bit, value in operations))
    set_mask = sum(1 << b for b, v in plan.items() if v)
    clear_mask = sum(1 << b for b, v in plan.items() if not v)
    assert state.read_pmc_bytes("R", 300, 300)[0] == (initial & ~clear_mask & 0xFF) | set_mask


# ---- parameter writes ------------------------------------------------------------------------------------
async def test_parameter_write_while_locked_is_access_denied_then_reads_back_after_unlock(
        client: PackedClient, state: MachineState) -> None:
    state.set_param_write_enable(False)
    with pytest.raises(AccessDenied) as info:
        await client.write_param(6713, 750)
    assert info.value.name == "EW_PASSWD"
    with pytest.raises(AccessDenied):
        await client.write_param_bit(1815, 0, True, axis=2)
    assert state.read_param_value(6713) == 500 and state.read_param_value(1815, 2) == 0b0011_0000
    state.set_param_write_enable(True)
    await client.write_param(6713, 750)
    assert (await client.read_params(6713))[0].value == 750
    await client.write_param_bit(1815, 0, True, axis=2)
    await client.write_param_bit(1815, 5, False, axis=2)
    assert (await client.read_params(1815, axis=2))[0].value == 0b0001_0001
    assert state.read_param_value(1815, 1) == 0b0011_0000  # the other axes untouched


async def test_locked_parameter_write_status_is_11_on_the_wire(server: PackedServer) -> None:
    server.state.set_param_write_enable(False)
    reply = await raw_call(server, pk.Command.WRPARAM, pk.encode_param_write(6713, 0, ParamType.TWO_WORD, 1))
    assert reply.payload == struct.pack("<h", 11)


async def test_parameter_write_of_the_wrong_width_is_ew_length(server: PackedServer) -> None:
    server.state.set_param_write_enable(True)
    word_for_a_long = pk.encode_param_write(6713, 0, ParamType.WORD, 1)
    assert (await raw_call(server, pk.Command.WRPARAM, word_for_a_long)).payload == struct.pack("<h", 2)
    assert server.state.read_param_value(6713) == 500


async def test_unknown_parameter_is_ew_number(client: PackedClient, state: MachineState) -> None:
    state.set_param_write_enable(True)
    with pytest.raises(OutOfRange):
        await client.write_param(4242, 1)
    (result,) = await client.batch([it.ReadParams(4242, 4242)])
    assert isinstance(result, OutOfRange)


# ---- symmetry: encode -> simulator store -> read back ---------------------------------------------------
@pytest.mark.parametrize("value", [12.345, 7, -0.125, 0.0, 99999.5, -2147.483647, 1e-9])
async def test_macro_round_trip(client: PackedClient, state: MachineState, value: float) -> None:
    await client.write_macro(520, value)
    assert state.read_macro(520) == value
    assert await client.read_macros(520) == [value]


@pytest.mark.parametrize(
    ("number", "axis", "value"),
    [(0, 0, 0b1010_0101),  # bit
     (20, 0, -3),  # byte
     (3281, 0, 15),  # byte
     (1825, 3, -1200),  # word
     (1850, 2, -123456),  # 2-word
     (6711, 0, 2_000_000_000),  # 2-word
     (1320, 1, 1234.567),  # real (30i)
     (1420, 4, 0.001)],  # real
)
async def test_parameter_round_trip_per_type(client: PackedClient, state: MachineState, number: int,
                                             axis: int, value: float) -> None:
    state.set_param_write_enable(True)
    await client.write_param(number, value, axis=axis)
    assert state.read_param_value(number, axis or 1) == value
    (record,) = await client.read_params(number, axis=axis)
    assert record.value == value


async def test_pmc_round_trip(client: PackedClient, state: MachineState) -> None:
    data = bytes(range(250, 256)) + bytes(range(6))
    await client.write_pmc("E", 10, data)
    assert state.read_pmc_bytes("E", 10, 21) == data
    assert await client.read_pmc("E", 10, 21) == list(data)


@pytest.mark.parametrize("area", sorted(pk.PMC_TYPE_A))
async def test_every_seed_area_letter_reaches_its_own_area(client: PackedClient, state: MachineState,
                                                           area: str) -> None:
    marker = bytes([0x40 + pk.PMC_TYPE_A[area]])
    await client.write_pmc(area, 5, marker)
    assert state.read_pmc_bytes(area, 5, 5) == marker


# ---- both transports over the same machine -----------------------------------------------------------------
async def test_fractional_macro_reads_back_through_both_transports(
        client: PackedClient, state: MachineState) -> None:
    native_server = pytest.importorskip("edge.sim.native_server")
    native_client = pytest.importorskip("edge.focas.client")
    await client.write_macro(530, 12.345)
    assert await client.read_macros(530) == [12.345]
    async with native_server.NativeServer(state, host="127.0.0.1", port=0) as native:
        cnc = native_client.FocasClient("127.0.0.1", native.port)
        async with cnc:
            assert await cnc.read_macros(530) == [12.345]
            await cnc.write_macro(531, -7.25)
            await cnc.write_pmc("D", 100, b"\x11\x22")
    assert await client.read_macros(531) == [-7.25]
    assert await client.read_pmc("D", 100, 101) == [0x11, 0x22]


# ---- a broken server --------------------------------------------------------------------------------------
async def test_garbage_from_the_server_is_a_protocol_error_and_the_session_resets() -> None:
    async def answer_garbage(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.read(65536)
        writer.write(b"\xa0\xa0\xa0\xa0\x00\x01\x01\x02")
        await writer.drain()
        await reader.read(65536)
        writer.close()

    garbage = await asyncio.start_server(answer_garbage, "127.0.0.1", 0)
    port = garbage.sockets[0].getsockname()[1]
    try:
        cnc = PackedClient(f"127.0.0.1:{port}", connect_timeout=2.0)
        with pytest.raises(ProtocolError, match="length"):
            await cnc.connect()
        assert not cnc.connected
    finally:
        garbage.close()
        await garbage.wait_closed()


async def test_wrong_echo_is_a_protocol_error(state: MachineState) -> None:
    async def wrong_seq(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        decoder = FrameDecoder()
        while data := await reader.read(65536):
            for frame in decoder.feed(data):
                body = pk.read_response(pk.encode_sysinfo(state.sysinfo()))
                writer.write(PackedFrame(frame.command, frame.seq + 1, body).encode())
        writer.close()

    liar = await asyncio.start_server(wrong_seq, "127.0.0.1", 0)
    port = liar.sockets[0].getsockname()[1]
    try:
        with pytest.raises(ProtocolError, match="seq"):
            await PackedClient(f"tcp:127.0.0.1:{port}", connect_timeout=2.0).connect()
    finally:
        liar.close()
        await liar.wait_closed()


async def test_command_missing_on_a_server_is_function_not_available(state: MachineState) -> None:
    """A bridge that lacks an extension id answers EW_FUNC; the item says so, the batch stands."""

    async def sysinfo_only(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        decoder = FrameDecoder()
        while data := await reader.read(65536):
            for frame in decoder.feed(data):
                if frame.command == pk.Command.SYSINFO:
                    body = pk.read_response(pk.encode_sysinfo(state.sysinfo()))
                else:
                    body = pk.encode_status(1)
                writer.write(PackedFrame(frame.command, frame.seq, body).encode())
        writer.close()

    bridge = await asyncio.start_server(sysinfo_only, "127.0.0.1", 0)
    port = bridge.sockets[0].getsockname()[1]
    try:
        async with PackedClient(f"127.0.0.1:{port}") as cnc:
            clock, info = await cnc.batch([it.ReadClock(), it.ReadSysInfo()])
            assert isinstance(clock, FunctionNotAvailable) and isinstance(clock, NotSupported)
            assert info == state.sysinfo()
    finally:
        bridge.close()
        await bridge.wait_closed()


# ---- the command line over the packed transport ----------------------------------------------------------
def test_cli_read_and_write_over_packed_tcp_and_unix(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    cli = pytest.importorskip("edge.cli")
    fleet_module = pytest.importorskip("edge.sim.fleet")
    fleet = fleet_module.Fleet([fleet_module.MachineSpec()], base_port=0, packed_base_port=0)
    thread = fleet_module.FleetThread(fleet)
    path = str(tmp_path / "cli.sock")
    with thread as running:
        machine = running[0]
        tcp = f"tcp:127.0.0.1:{machine.packed_port}"
        assert cli.main(["write", "--transport", "packed", tcp, "macro:540=12.345"]) == 0
        assert machine.state.read_macro(540) == 12.345
        handle = thread.call(lambda: start_packed_server(machine.state, unix_path=path))
        try:
            capsys.readouterr()
            assert cli.main(["read", "--transport", "packed", "--json", f"unix:{path}", "macro:540"]) == 0
            assert "12.345" in capsys.readouterr().out
            assert cli.main(["write", "--transport", "packed", f"unix:{path}", "param:6713=1"]) == 1  # locked
            assert "EW_PASSWD" in capsys.readouterr().err
        finally:
            thread.call(handle.close)


async def test_work_offsets_come_from_the_simulators_packed_server(state: MachineState,
                                                                    client: PackedClient) -> None:
    [g54, g55] = await client.batch([it.ReadWorkOffsets(1), it.ReadWorkOffsets(2)])
    assert g54 == state.work_offsets(1) and g55 == state.work_offsets(2)
    assert len(g54) == state.profile.axis_count and g54 != g55
    with pytest.raises(OutOfRange, match="cnc_rdzofs"):
        await client.read(it.ReadWorkOffsets(7))


async def test_modal_g_codes_and_tool_number_come_from_the_simulators_packed_server(
        state: MachineState, client: PackedClient) -> None:
    modal, tool = await client.batch([it.ReadModalGCodes(), it.ReadToolNumber()])
    assert {m.group: m.code for m in modal}[13] == "G54" and {m.group for m in modal} == {
        m.group for m in state.modal_g_codes()}
    assert 1 <= tool <= 4


async def test_the_request_log_keeps_only_the_latest_requests(monkeypatch: pytest.MonkeyPatch,
                                                              state: MachineState) -> None:
    monkeypatch.setattr(packed_endpoint, "REQUEST_LOG", 3)
    async with await start_packed_server(state) as server, PackedClient(server.address) as cnc:
        for number in range(100, 105):
            await cnc.read_macros(number)
        assert [pk.decode_macro_read(r.payload) for r in server.requests_for(pk.Command.RDMACRO)] == [
            102, 103, 104]
