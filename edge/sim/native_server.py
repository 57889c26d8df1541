"""The simulated CNC's native FOCAS/Ethernet server: the wire protocol over one MachineState.

This module is the connection side: sessions, PDU framing, faults, counters. What a data PDU answers
comes from the fast path (edge.sim.native_plans), which gives the bytes of the reference answer path
(edge.sim.native_handlers, one handler per function over the client's own codecs).

Open (0x0101) answers 0x0102, close (0x0201) answers 0x0202 and ends the session, data (0x2101)
answers 0x2102. The header version of answers follows the profile (2, 3 or 4). Faults (edge.sim.faults)
are applied per request (a data request while an `ew` fault is set is answered by the reference path);
ServerStats counts PDUs so tests can assert "ten items went as one request".
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from edge.focas.errors import ProtocolError
from edge.focas.frame import (
    Frame,
    FrameDecoder,
    PduType,
    encode_close_response,
    encode_open_response,
    encode_response,
)
from edge.focas.function_entry import Context
from edge.focas.functions import READ_CLOCK
from edge.sim.faults import GARBAGE, FaultPlan
from edge.sim.native_handlers import answer_subpacket
from edge.sim.native_plans import AnswerPlan, AnswerPlans, encode_planned_response
from edge.sim.state import MachineState

CLOCK_COMMAND = READ_CLOCK.command

log = logging.getLogger(__name__)

# The only published open reply is 360 bytes starting 00 08; what the rest means is unknown.
OPEN_REPLY_PAYLOAD = b"\x00\x08" + bytes(358)


@dataclass
class ServerStats:
    """What the server has seen; `data_pdus` is the request counter tests assert on."""

    connections: int = 0
    refused: int = 0
    open_pdus: int = 0
    data_pdus: int = 0
    close_pdus: int = 0
    subpackets: int = 0
    last_batch: int = 0  # subpackets in the latest data PDU
    clock_pdus: int = 0  # data PDUs that read the clock and nothing else (a collector's clock-only reads)
    commands: Counter[int] = field(default_factory=Counter)

    def describe(self) -> dict[str, Any]:
        return {"connections": self.connections, "refused": self.refused, "open_pdus": self.open_pdus,
                "data_pdus": self.data_pdus, "close_pdus": self.close_pdus, "subpackets": self.subpackets,
                "last_batch": self.last_batch, "clock_pdus": self.clock_pdus}


class NativeServer:
    """Serves one MachineState on host:port (port 0 = any free port) with faults from `faults`."""

    def __init__(self, state: MachineState, faults: FaultPlan | None = None, *, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        self.state = state
        self.faults = faults or FaultPlan()
        self.host = host
        self.port = port
        self.stats = ServerStats()
        self.context = Context.from_sysinfo(state.sysinfo())
        self.plans = AnswerPlans(state)
        self._server: asyncio.Server | None = None
        self._sessions: set[asyncio.Transport] = set()

    @property
    def sessions(self) -> int:
        """Connections now open."""
        return len(self._sessions)

    async def start(self) -> int:
        """Start listening; returns the bound port."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(self._session, self.host, self.port)
        self.port = int(self._server.sockets[0].getsockname()[1])
        log.info("native FOCAS serving machine=%s profile=%s port=%d", self.state.name,
                 self.state.profile.name, self.port)
        return self.port

    async def close(self) -> None:
        if self._server is None:
            return
        self._server.close()
        self.drop_connections()
        await self._server.wait_closed()
        self._server = None

    def drop_connections(self) -> int:
        """Abort every open session now (RST, no FIN handshake); returns how many."""
        dropped = list(self._sessions)
        for transport in dropped:
            transport.abort()
        self._sessions.clear()
        return len(dropped)

    async def __aenter__(self) -> NativeServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ---- one connection ----------------------------------------------------------------------------
    def _session(self) -> _Session:
        return _Session(self)

    def _answer_data(self, body: bytes, transport: asyncio.WriteTransport, version: int) -> str:
        """Answer one data PDU: "ok", or "dropped" / "hang" when the conversation must end."""
        plans = self.plans.for_body(body, self.context)
        self.stats.data_pdus += 1
        self.stats.subpackets += len(plans)
        self.stats.last_batch = len(plans)
        commands = [plan.command for plan in plans]
        self.stats.commands.update(commands)
        if commands and all(command == CLOCK_COMMAND for command in commands):
            self.stats.clock_pdus += 1
        if self.faults.take_drop():
            transport.abort()
            return "dropped"
        if self.faults.take_garbage():
            transport.write(GARBAGE)
            return "ok"
        reply = self.reply(plans, version)
        if self.faults.take_hang() or self._take_hang_on(plans):
            transport.write(reply[: max(1, len(reply) // 2)])
            return "hang"
        transport.write(reply)
        return "ok"

    def answer_body(self, body: bytes, version: int) -> bytes:
        """The 0x2102 PDU for a 0x2101 body, without stats or connection faults (tests, benchmarks)."""
        return self.reply(self.plans.for_body(body, self.context), version)

    def reply(self, plans: Sequence[AnswerPlan], version: int) -> bytes:
        """The answer PDU now; forced EW codes are per subpacket, by command or name: the reference's job."""
        self.state.pin_moment()
        try:
            if self.faults.ew:
                answers = [answer_subpacket(self.state, plan.request, self.faults, self.context) for plan in plans]
                return encode_response(answers, version)
            return encode_planned_response(plans, version)
        finally:
            self.state.unpin_moment()

    def _take_hang_on(self, plans: Sequence[AnswerPlan]) -> bool:
        """faults.take_hang_on for this request (skipped when no hang_on is set: it would change nothing)."""
        if not self.faults.hang_on:
            return False
        return self.faults.take_hang_on([(plan.command, plan.name) for plan in plans])


class _Session(asyncio.Protocol):
    """One client connection, answered in the transport's callbacks: no reader task, no future per read.

    A frame is answered as soon as it is decoded; only a latency fault needs the loop's time, so while one
    is set (or frames wait behind one) frames queue for a task that sleeps before each, in order. After a
    hang the session reads and ignores everything until the peer gives up (no FIN from us).
    """

    def __init__(self, server: NativeServer) -> None:
        self.server = server
        self.decoder = FrameDecoder()
        self.version = server.state.profile.response_version
        self.transport: asyncio.Transport | None = None
        self.peer: Any = None
        self.silent = False  # after a hang: ignore the peer
        self.over = False  # the conversation has ended (closed, dropped, refused, lost)
        self.backlog: deque[Frame] | None = None  # frames waiting behind a latency fault
        self.slow: asyncio.Task[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        server = self.server
        server.stats.connections += 1
        limit = server.faults.max_sessions
        if server.faults.take_refuse() or (limit is not None and len(server._sessions) >= limit):
            server.stats.refused += 1
            self.over = True
            transport.abort()
            return
        self.transport = transport
        self.peer = transport.get_extra_info("peername")
        server._sessions.add(transport)

    def connection_lost(self, exc: Exception | None) -> None:
        self.over = True
        if self.transport is not None:
            self.server._sessions.discard(self.transport)
        if self.slow is not None:
            self.slow.cancel()

    def pause_writing(self) -> None:  # the peer reads slower than we answer: stop reading (a stream's drain)
        if self.transport is not None:
            self.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.transport is not None and not self.over:
            self.transport.resume_reading()

    def eof_received(self) -> bool | None:
        return None  # the peer is done (or gave up on a hang): close our side

    def data_received(self, data: bytes) -> None:
        if self.over or self.silent:
            return
        try:
            frames = self.decoder.feed(data)
        except ProtocolError as exc:
            log.warning("client sent a malformed frame machine=%s peer=%s error=%s",
                        self.server.state.name, self.peer, exc)
            self._end()
            return
        for frame in frames:
            if self.backlog is not None or self.server.faults.latency > 0:
                self._later(frame)
            elif not self._answer(frame):
                return

    def _answer(self, frame: Frame) -> bool:
        """Answer one frame now; False when the conversation is over."""
        transport, server = self.transport, self.server
        assert transport is not None
        if frame.type == PduType.DATA_REQUEST:
            outcome = server._answer_data(frame.body, transport, self.version)
            if outcome == "hang":
                self.silent = True
            elif outcome != "ok":
                self.over = True
            return outcome == "ok"
        if frame.type == PduType.OPEN_REQUEST:
            server.stats.open_pdus += 1
            transport.write(encode_open_response(OPEN_REPLY_PAYLOAD, self.version))
            return True
        if frame.type == PduType.CLOSE_REQUEST:
            server.stats.close_pdus += 1
            transport.write(encode_close_response(self.version))
        else:
            log.warning("unsupported PDU type 0x%04x machine=%s; closing", frame.type, server.state.name)
        self._end()
        return False

    def _end(self) -> None:
        """Close our side once what was written has gone out."""
        self.over = True
        if self.transport is not None:
            self.transport.close()

    def _later(self, frame: Frame) -> None:
        if self.backlog is None:
            self.backlog = deque()
            self.slow = asyncio.get_running_loop().create_task(self._answer_slowly())
        self.backlog.append(frame)

    async def _answer_slowly(self) -> None:
        """Frames behind a latency fault, in order, each after the latency set when it comes up."""
        backlog = self.backlog
        assert backlog is not None
        try:
            while backlog and not self.over and not self.silent:
                latency = self.server.faults.latency
                if latency > 0:
                    await asyncio.sleep(latency)
                if self.over or self.silent or not self._answer(backlog.popleft()):
                    break
        except asyncio.CancelledError:
            pass  # the connection went, or the simulator is shutting down
        finally:
            self.backlog = None
            self.slow = None
