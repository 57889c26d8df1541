"""FocasClient edge cases over real TCP against a tiny scripted CNC in the test (not the simulator).

The scripted peer answers with the shared function table, and on demand misbehaves: it stalls
mid-frame, sends garbage, echoes the wrong command, miscounts subpackets, dribbles bytes one at a time,
or hangs up mid-frame.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from datetime import datetime, time
from typing import Any

import pytest

from edge import ConfigError
from edge.focas import function_entry as fe
from edge.focas import functions as fn
from edge.focas import items as it
from edge.focas.client import FocasClient
from edge.focas.connect import open_session, parse_address
from edge.focas.errors import (
    EW_FUNC,
    ConnectionLost,
    FocasTimeout,
    FunctionNotAvailable,
    NotSupported,
    ProtocolError,
)
from edge.focas.frame import (
    FrameDecoder,
    PduType,
    RequestSubpacket,
    ResponseSubpacket,
    decode_request_body,
    encode_close_response,
    encode_open_response,
    encode_response,
)
from edge.focas.function_entry import Context
from edge.focas.model import ParamRecord, PmcType, StatInfo, SysInfo
from edge.focas.values import decode_pmc
from tests.helpers import async_wait_for

SYSINFO_16I = SysInfo(0, 8, "16", " M", "B0H1", "0020", "04")
SYSINFO_31I = SysInfo(0x0200, 32, "31", " M", "G421", "08.0", "04")
CLOCK = datetime(2024, 5, 14, 12, 15, 5)


class ScriptedCnc:
    """A TCP peer that answers FOCAS requests from canned values and fails the way `fault` says."""

    def __init__(self, sysinfo: SysInfo = SYSINFO_16I) -> None:
        self.sysinfo = sysinfo
        self.ctx = Context.from_sysinfo(sysinfo)
        self.fault: str | None = None
        self.errors: dict[int, int] = {}  # command -> EW code
        self.requests: list[list[RequestSubpacket]] = []
        self.frame_types: list[int] = []
        self.writes: list[tuple[str, Any]] = []
        self.macros: dict[int, float | None] = {500: 1.25, 501: None}
        self.pmc = bytearray(256)
        self.release = asyncio.Event()
        self.connections = 0
        self.server: asyncio.Server | None = None
        self.port = 0

    async def start(self) -> None:
        self.server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.port = self.server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        self.release.set()
        if self.server is not None:
            self.server.close()
            await self.server.wait_closed()

    @property
    def data_requests(self) -> int:
        return len(self.requests)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        decoder = FrameDecoder(versions={1})
        try:
            while data := await reader.read(4096):
                for frame in decoder.feed(data):
                    self.frame_types.append(frame.type)
                    if frame.type == PduType.OPEN_REQUEST:
                        writer.write(encode_open_response(bytes(360), version=4))
                    elif frame.type == PduType.CLOSE_REQUEST:
                        writer.write(encode_close_response(version=4))
                    else:
                        requests = decode_request_body(frame.body)
                        self.requests.append(requests)
                        await self._answer(writer, requests)
                    await writer.drain()
        except (ConnectionError, ProtocolError):
            pass
        finally:
            writer.close()

    async def _answer(self, writer: asyncio.StreamWriter, requests: list[RequestSubpacket]) -> None:
        answers = [self._answer_one(req) for req in requests]
        fault = self.fault if len(self.requests) > 1 else None  # the connect's sysinfo stays clean
        if fault == "wrong_echo":
            answers[0] = ResponseSubpacket(answers[0].cls, answers[0].command + 1, payload=answers[0].payload)
        if fault == "miscount":
            answers = answers[:-1]
        data = encode_response(answers, version=4)
        if fault == "garbage":
            data = b"HTTP/1.1 400 Bad Request\r\n\r\n"
        if fault == "stall":
            writer.write(data[: len(data) // 2])
            await writer.drain()
            await self.release.wait()
            return
        if fault == "hangup":
            writer.write(data[:15])
            await writer.drain()
            writer.close()
            return
        if fault == "dribble":
            for byte in data:
                writer.write(bytes([byte]))
                await writer.drain()
            return
        writer.write(data)

    def _answer_one(self, req: RequestSubpacket) -> ResponseSubpacket:
        function = fn.BY_COMMAND.get((req.cls, req.command))
        if function is None:
            return fe.error_response(req, EW_FUNC)
        if req.command in self.errors:
            return fe.error_response(req, self.errors[req.command])
        if function.is_write:
            assert function.decode_extra is not None
            self.writes.append((function.name, function.decode_extra(req, self.ctx)))
            return function.response(req, None, self.ctx)
        return function.response(req, self._value(function, req), self.ctx)

    def _value(self, function: fe.Function, req: RequestSubpacket) -> Any:
        args = req.args
        if function is fn.SYSINFO:
            return self.sysinfo
        if function is fn.STATINFO:
            return StatInfo(1, 3, 1, 0, 0, 0, 0)
        if function is fn.READ_MACROS:
            return [self.macros.get(n) for n in range(args[0], args[1] + 1)]
        if function is fn.ACTUAL_FEED:
            return 1250.5
        if function in (fn.READ_PARAMS_4, fn.READ_PARAMS_8):
            return [ParamRecord(n, 0, 3, (n * 10,)) for n in range(args[0], args[1] + 1)]
        if function in (fn.READ_DIAG_4, fn.READ_DIAG_8):
            return [ParamRecord(n, 0, 4, (1.5,)) for n in range(args[0], args[1] + 1)]
        if function is fn.READ_PMC:
            return decode_pmc(bytes(self.pmc[args[0] : args[1] + 1]), PmcType(args[3]))
        if function is fn.READ_CLOCK:
            return CLOCK
        if function is fn.AXIS_NAMES:
            return ["X", "Y", "Z"]
        raise AssertionError(f"no canned value for {function.name}")


@pytest.fixture
async def cnc() -> AsyncIterator[ScriptedCnc]:
    peer = ScriptedCnc()
    await peer.start()
    try:
        yield peer
    finally:
        await peer.stop()


@contextlib.asynccontextmanager
async def client_for(peer: ScriptedCnc, **kw: Any) -> AsyncIterator[FocasClient]:
    client = FocasClient("127.0.0.1", peer.port, timeout=kw.pop("timeout", 2.0), connect_timeout=2.0, **kw)
    await client.connect()
    try:
        yield client
    finally:
        await client.close()


BATCH = [it.ReadStatus(), it.ReadMacros(500, 501), it.ReadFeed(), it.ReadParams(6711, 6712),
         it.ReadPmc("R", 0, 3), it.ReadClock(), it.ReadAxisNames(), it.ReadAlarmHistory()]


async def test_batch_is_one_pdu_with_results_in_order(cnc: ScriptedCnc) -> None:
    async with client_for(cnc) as client:
        assert client.sysinfo == SYSINFO_16I
        before = cnc.data_requests
        results = await client.batch(BATCH)
        assert cnc.data_requests == before + 1
        assert len(cnc.requests[-1]) == 8  # 7 items, the clock takes 2, alarm history none
    assert results[0] == StatInfo(1, 3, 1, 0, 0, 0, 0)
    assert results[1] == [1.25, None]
    assert results[2] == 1250.5
    assert results[3] == [ParamRecord(6711, 0, 3, (67110,)), ParamRecord(6712, 0, 3, (67120,))]
    assert results[4] == [0, 0, 0, 0]
    assert results[5] == CLOCK
    assert results[6] == ["X", "Y", "Z"]
    assert isinstance(results[7], NotSupported)
    assert cnc.frame_types[0] == PduType.OPEN_REQUEST and cnc.frame_types[-1] == PduType.CLOSE_REQUEST


async def test_30i_sysinfo_selects_the_8_byte_forms(cnc: ScriptedCnc) -> None:
    cnc.sysinfo, cnc.ctx = SYSINFO_31I, Context.from_sysinfo(SYSINFO_31I)
    async with client_for(cnc) as client:
        records = await client.read_params(6711)
        diag = await client.read_diag(918, 918)
    assert records == [ParamRecord(6711, 0, 3, (67110,))]
    assert diag == [ParamRecord(918, 0, 4, (1.5,))]
    assert [req.command for req in cnc.requests[-2]] == [0x8D]
    assert [req.command for req in cnc.requests[-1]] == [0x93]


async def test_an_item_error_does_not_fail_the_others(cnc: ScriptedCnc) -> None:
    cnc.errors[0x24] = EW_FUNC
    async with client_for(cnc) as client:
        status, feed, macros = await client.batch([it.ReadStatus(), it.ReadFeed(), it.ReadMacros(500, 500)])
        assert client.connected
    assert isinstance(feed, FunctionNotAvailable) and feed.code == EW_FUNC and feed.function == "actual_feed"
    assert status == StatInfo(1, 3, 1, 0, 0, 0, 0) and macros == [1.25]


async def test_answers_dribbled_one_byte_at_a_time(cnc: ScriptedCnc) -> None:
    cnc.fault = "dribble"
    async with client_for(cnc) as client:
        assert await client.batch(BATCH[:3]) == [StatInfo(1, 3, 1, 0, 0, 0, 0), [1.25, None], 1250.5]


async def test_stall_mid_frame_times_out_resets_and_reconnects(cnc: ScriptedCnc) -> None:
    client = FocasClient("127.0.0.1", cnc.port, timeout=0.3, connect_timeout=2.0)
    await client.connect()
    try:
        cnc.fault = "stall"
        with pytest.raises(FocasTimeout, match=r"no complete answer within 0\.3s"):
            await client.read_status()
        assert not client.connected
        with pytest.raises(ConnectionLost, match="not connected"):
            await client.read_status()
        cnc.fault = None
        await client.connect()
        assert await client.read_status() == StatInfo(1, 3, 1, 0, 0, 0, 0)
        assert cnc.connections == 2
    finally:
        await client.close()


@pytest.mark.parametrize("fault,message", [
    ("garbage", "expected sync a0a0a0a0 at frame start, got 48545450"),
    ("wrong_echo",
     "subpacket 0 should echo class 1 path 1 command 0x0019, got class 1 path 1 command 0x001a"),
    ("miscount", "expected 2 subpackets in the answer, got 1"),
])
async def test_malformed_answers_raise_protocol_error_and_reset(cnc: ScriptedCnc, fault: str,
                                                                message: str) -> None:
    client = FocasClient("127.0.0.1", cnc.port, timeout=2.0, connect_timeout=2.0)
    await client.connect()
    try:
        cnc.fault = fault
        with pytest.raises(ProtocolError, match=message):
            await client.batch([it.ReadStatus(), it.ReadFeed()])
        assert not client.connected
        cnc.fault = None
        await client.connect()
        assert await client.read_status() == StatInfo(1, 3, 1, 0, 0, 0, 0)
    finally:
        await client.close()


async def test_hangup_mid_frame_is_connection_lost(cnc: ScriptedCnc) -> None:
    client = FocasClient("127.0.0.1", cnc.port, timeout=2.0, connect_timeout=2.0)
    await client.connect()
    try:
        cnc.fault = "hangup"
        with pytest.raises(ConnectionLost, match="peer closed the connection"):
            await client.read_status()
        assert not client.connected
    finally:
        await client.close()


async def test_refused_connection_is_connection_lost() -> None:
    peer = ScriptedCnc()
    await peer.start()
    port = peer.port
    await peer.stop()
    with pytest.raises(ConnectionLost):
        await FocasClient("127.0.0.1", port, connect_timeout=2.0).connect()


async def test_many_tasks_share_one_client(cnc: ScriptedCnc) -> None:
    async with client_for(cnc) as client:
        results = await asyncio.gather(*(client.read_macros(500) for _ in range(20)),
                                       *(client.read_status() for _ in range(20)))
    assert results[:20] == [[1.25]] * 20
    assert results[20:] == [StatInfo(1, 3, 1, 0, 0, 0, 0)] * 20


async def test_large_batches_split_at_the_subpacket_limit(cnc: ScriptedCnc) -> None:
    async with client_for(cnc, max_subpackets=4) as client:
        before = cnc.data_requests
        results = await client.batch([it.ReadMacros(500, 500)] * 3 + [it.ReadClock()] + [it.ReadFeed()] * 3)
        assert [len(r) for r in cnc.requests[before:]] == [3, 4, 1]  # the clock pair stays together
    assert results[3] == CLOCK and results[-1] == 1250.5


async def test_writes(cnc: ScriptedCnc) -> None:
    async with client_for(cnc) as client:
        await client.write_macro(500, 1.1)
        await client.write_macro(501, 5e12)  # no i32 mantissa can carry it: IEEE double form
        await client.write_pmc("R", 10, bytes(range(40)))
        await client.set_clock(datetime.combine(CLOCK.date(), time(8, 0, 1)))
        with pytest.raises(NotSupported, match="date"):
            await client.set_clock(datetime(2030, 1, 1, 8, 0))
        with pytest.raises(NotSupported, match="write_param"):
            await client.write_param(6711, 0)
        cnc.errors[0x16] = 17
        with pytest.raises(Exception, match="EW_PASSWD") as caught:
            await client.write_macro(500, 2.0)
        assert caught.value.__class__.__name__ == "AccessDenied"
        assert client.connected
    assert cnc.writes == [
        ("write_macros", [1.1]),
        ("write_macro_double", 5e12),
        ("write_pmc", bytes(range(32))),
        ("write_pmc", bytes(range(32, 40))),
        ("set_time", time(8, 0, 1)),
    ]


async def test_close_sends_the_close_pdu_and_never_raises(cnc: ScriptedCnc) -> None:
    client = FocasClient("127.0.0.1", cnc.port, timeout=2.0)
    await client.connect()
    await client.close()
    await async_wait_for(lambda: PduType.CLOSE_REQUEST in cnc.frame_types, 5.0, message="close PDU")
    await client.close()  # twice is fine


async def test_capabilities(cnc: ScriptedCnc) -> None:
    caps = FocasClient("127.0.0.1", cnc.port).capabilities
    assert caps.transport == "focas"
    assert all(caps.can(op) for op in ("ReadMacros", "ReadClock", "write_macro", "write_pmc", "set_clock"))
    assert not caps.can("write_param") and not caps.can("ReadAlarmHistory")


def test_open_session_and_addresses() -> None:
    session = open_session("focas", "tcp:10.1.2.3:9000", timeout=1.0)
    assert isinstance(session, FocasClient) and (session.host, session.port) == ("10.1.2.3", 9000)
    assert session.timeout == 1.0
    assert parse_address("cnc-7").port == 8193
    assert parse_address("[fe80::1]:8194").host == "fe80::1"
    assert parse_address("unix:/run/cnc.sock").unix_path == "/run/cnc.sock"
    for bad in ("host:notaport", "host:70000", ":8193", "unix:"):
        with pytest.raises(ConfigError):
            parse_address(bad)
    with pytest.raises(ConfigError, match="TCP only"):
        open_session("focas", "unix:/run/cnc.sock")
    packed = open_session("packed", "unix:/run/cnc.sock")  # imported lazily, address passed through
    assert packed.transport == "packed"
    with pytest.raises(ConfigError, match="expected one of focas, packed"):
        open_session("serial", "x")



async def test_a_repeated_batch_reuses_its_request_and_unchanged_values(cnc: ScriptedCnc) -> None:
    batch = (it.ReadMacros(500, 501), it.ReadFeed(), it.ReadClock())  # a tuple: the poller's form
    async with client_for(cnc) as client:
        first = await client.batch(batch)
        second = await client.batch(batch)
        cnc.macros[500] = 2.5
        third = await client.batch(batch)
    assert cnc.requests[-1] == cnc.requests[-2] == cnc.requests[-3]  # same subpackets every time
    assert second[0] is first[0] and second[1] == first[1]  # same answer bytes: the same value object
    assert third[0] == [2.5, None] and third[0] is not first[0]  # changed bytes: decoded afresh
    assert first[0] == [1.25, None]


async def test_batches_sharing_an_item_share_what_was_last_answered(cnc: ScriptedCnc) -> None:
    """A poller's tick shapes (status only; status + macros) overlap: a value decoded in one shape that
    equals the item's value from the other is handed back as that object, so an unchanged item keeps
    its value object from one shape to the other."""
    feed = it.ReadFeed()
    small, large = (feed, it.ReadClock()), (it.ReadMacros(500, 501), feed, it.ReadClock())
    async with client_for(cnc) as client:
        first = await client.batch(small)
        second = await client.batch(large)
        cnc.macros[500] = 3.0
        third = await client.batch(large)
        fourth = await client.batch(small)
    assert second[1] is first[0] and third[1] is first[0] and fourth[0] is first[0]
    assert second[0] == [1.25, None] and third[0] == [3.0, None]


async def test_tick_shapes_keep_one_last_answer_per_item_and_see_each_others_changes(cnc: ScriptedCnc) -> None:
    """Each item's last answer is kept once per session, whichever batch asked it: a change one batch brought
    and that was undone before the other batch asks again is decoded again there (its bytes differ from the
    last answer the session holds), and an item asked twice in one batch is answered twice."""
    macros, feed = it.ReadMacros(500, 501), it.ReadFeed()
    small, large = (macros, it.ReadClock()), (macros, feed, it.ReadClock(), feed)
    async with client_for(cnc) as client:
        first = await client.batch(small)
        cnc.macros[500] = 3.0
        second = await client.batch(large)
        cnc.macros[500] = 1.25
        third = await client.batch(small)
        fourth = await client.batch(large)
        pieces = len(client._memo.answers.pieces)
    assert first[0] == third[0] == fourth[0] == [1.25, None] and second[0] == [3.0, None]
    assert second[1] == second[3] == fourth[1] == 1250.5
    assert fourth[0] is third[0]  # unchanged since the other batch asked: the same object
    assert pieces == 5  # macros, the clock's date and time, feed twice: once each, not once per batch


async def test_sessions_polling_alike_share_the_request_bytes_not_the_values(cnc: ScriptedCnc) -> None:
    batch = (it.ReadMacros(500, 501), it.ReadClock())
    async with client_for(cnc) as one, client_for(cnc) as other:
        await one.batch(batch)
        first = await other.batch(batch)
        cnc.macros[500] = 7.0
        second = await other.batch(batch)
        (pdu_one,), (pdu_other,) = one._prepare(batch).pdus, other._prepare(batch).pdus
    assert pdu_one.layout is pdu_other.layout  # one encoded request for both machines
    assert first[0] == [1.25, None] and second[0] == [7.0, None]
    assert one._memo is not other._memo


async def test_a_list_batch_is_decoded_every_time(cnc: ScriptedCnc) -> None:
    batch = [it.ReadMacros(500, 501)]  # a list may change between calls: never cached
    async with client_for(cnc) as client:
        first = await client.batch(batch)
        batch[0] = it.ReadMacros(501, 501)
        second = await client.batch(batch)
    assert first[0] == [1.25, None] and second[0] == [None]


async def test_an_item_error_is_not_remembered_as_a_value(cnc: ScriptedCnc) -> None:
    batch = (it.ReadMacros(500, 501), it.ReadFeed())
    async with client_for(cnc) as client:
        cnc.errors[fn.ACTUAL_FEED.command] = EW_FUNC
        failed = await client.batch(batch)
        cnc.errors.clear()
        recovered = await client.batch(batch)
    assert isinstance(failed[1], FunctionNotAvailable) and failed[0] == [1.25, None]
    assert recovered[1] == 1250.5


async def test_a_new_session_prepares_its_batches_again(cnc: ScriptedCnc) -> None:
    batch = (it.ReadParams(6711, 6711),)
    async with client_for(cnc) as client:
        before = await client.batch(batch)
        await client.reset()
        cnc.sysinfo, cnc.ctx = SYSINFO_31I, Context.from_sysinfo(SYSINFO_31I)
        await client.connect()
        after = await client.batch(batch)
    assert before == after == [[ParamRecord(6711, 0, 3, (67110,))]]
    assert [req.command for req in cnc.requests[-1]] == [0x8D]  # the 30i form, not the cached 0x0e PDU
