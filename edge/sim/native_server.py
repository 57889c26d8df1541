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
import contextlib
import logging
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from edge.focas.errors import ProtocolError
from edge.focas.frame import (
    FrameDecoder,
    PduType,
    encode_close_response,
    encode_open_response,
    encode_response,
)
from edge.focas.functions import READ_CLOCK, Context
from edge.sim.faults import GARBAGE, FaultPlan
from edge.sim.native_handlers import answer_subpacket
from edge.sim.native_plans import AnswerPlan, AnswerPlans, encode_planned_response
from edge.sim.state import MachineState

CLOCK_COMMAND = READ_CLOCK.command

log = logging.getLogger(__name__)

READ_SIZE = 65536
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
        self._sessions: set[asyncio.StreamWriter] = set()

    @property
    def sessions(self) -> int:
        """Connections now open."""
        return len(self._sessions)

    async def start(self) -> int:
        """Start listening; returns the bound port."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
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
        for writer in dropped:
            writer.transport.abort()
        self._sessions.clear()
        return len(dropped)

    async def __aenter__(self) -> NativeServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ---- one connection ----------------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.stats.connections += 1
        limit = self.faults.max_sessions
        if self.faults.take_refuse() or (limit is not None and len(self._sessions) >= limit):
            self.stats.refused += 1
            writer.transport.abort()
            return
        self._sessions.add(writer)
        peer = writer.get_extra_info("peername")
        try:
            await self._converse(reader, writer)
        except ProtocolError as exc:
            log.warning("client sent a malformed frame machine=%s peer=%s error=%s",
                        self.state.name, peer, exc)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        except asyncio.CancelledError:
            # The simulator is shutting down. Ending cancelled would make asyncio's stream callback log
            # a CancelledError traceback for a connection nobody is waiting on.
            pass
        finally:
            self._sessions.discard(writer)
            writer.close()
        with contextlib.suppress(Exception, asyncio.CancelledError):
            await writer.wait_closed()

    async def _converse(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        decoder = FrameDecoder()
        version = self.state.profile.response_version
        while data := await reader.read(READ_SIZE):
            for frame in decoder.feed(data):
                if self.faults.latency > 0:
                    await asyncio.sleep(self.faults.latency)
                if frame.type == PduType.OPEN_REQUEST:
                    self.stats.open_pdus += 1
                    writer.write(encode_open_response(OPEN_REPLY_PAYLOAD, version))
                elif frame.type == PduType.CLOSE_REQUEST:
                    self.stats.close_pdus += 1
                    writer.write(encode_close_response(version))
                    await writer.drain()
                    return
                elif frame.type == PduType.DATA_REQUEST:
                    outcome = await self._answer_data(frame.body, writer, version)
                    if outcome == "hang":
                        await _stay_silent(reader)
                    if outcome != "ok":
                        return
                else:
                    log.warning("unsupported PDU type 0x%04x machine=%s; closing",
                                frame.type, self.state.name)
                    return
            await writer.drain()

    async def _answer_data(self, body: bytes, writer: asyncio.StreamWriter, version: int) -> str:
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
            writer.transport.abort()
            return "dropped"
        if self.faults.take_garbage():
            writer.write(GARBAGE)
            return "ok"
        reply = self.reply(plans, version)
        if self.faults.take_hang() or self._take_hang_on(plans):
            writer.write(reply[: max(1, len(reply) // 2)])
            await writer.drain()
            return "hang"
        writer.write(reply)
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


async def _stay_silent(reader: asyncio.StreamReader) -> None:
    """Hang: keep the socket open, read and ignore, say nothing until the peer gives up (no FIN from us)."""
    while await reader.read(READ_SIZE):
        pass
