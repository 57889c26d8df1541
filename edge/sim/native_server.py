"""The simulated CNC's native FOCAS/Ethernet server: the wire protocol over one MachineState.

Byte layouts are not written here: requests are parsed and answers built with the same codecs the
client uses (edge.focas.frame and the function table in edge.focas.functions). For every request
subpacket the server finds the function by (class, command), asks the machine state for the typed
value (or applies the write) and lets the table encode the payload; a CncError from the state becomes
that subpacket's EW code. One answer subpacket per request subpacket, in order, each with its own rc.

Open (0x0101) answers 0x0102, close (0x0201) answers 0x0202 and ends the session, data (0x2101)
answers 0x2102. The header version of answers follows the profile (2, 3 or 4). Unknown commands, and
the parameter/diagnosis form the profile does not have, answer EW_FUNC. Faults (edge.sim.faults) are
applied per request; ServerStats counts PDUs so tests can assert "ten items went as one request".
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from edge.focas import functions as fn
from edge.focas.errors import (
    EW_ATTRIB,
    EW_FUNC,
    EW_LENGTH,
    EW_NOOPT,
    EW_NUMBER,
    EW_PATH,
    CncError,
    ProtocolError,
    cnc_error,
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
from edge.focas.functions import Context, Function, error_response
from edge.focas.model import PmcType
from edge.sim.faults import GARBAGE, FaultPlan
from edge.sim.state import MachineState

log = logging.getLogger(__name__)

PROTOCOL = "native"  # the name writes carry in the machine's write log
READ_SIZE = 65536
# The only published open reply is 360 bytes starting 00 08; what the rest means is unknown.
OPEN_REPLY_PAYLOAD = b"\x00\x08" + bytes(358)
# 0x26 position type codes: pyfanuc's (4 abs, 1 machine, 6 rel, 7 distance) and HSL's (0 abs, 2 rel).
POSITION_KINDS = {4: "absolute", 0: "absolute", 1: "machine", 6: "relative", 2: "relative", 7: "distance"}
PMC_AREA_BY_CODE = {code: letter for letter, code in fn.PMC_ADR_TYPES.items()}

Handler = Callable[[MachineState, RequestSubpacket, Context], Any]


# ---- one handler per function: (state, request, ctx) -> typed value for the table to encode -----------
def _positions(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[float]:
    kind = POSITION_KINDS.get(req.args[0])
    if kind is None:
        raise cnc_error(EW_NOOPT, "cnc_position", message=f"position type {req.args[0]} not available")
    return _per_axis(state.positions(kind), req.args[1], "cnc_position")


def _per_axis(values: list[float], axis: int, function: str) -> list[float]:
    """axis -1 (or 0): every axis; n: that one."""
    if axis in (-1, 0):
        return values
    if 1 <= axis <= len(values):
        return [values[axis - 1]]
    raise cnc_error(EW_ATTRIB, function, message=f"axis {axis} is outside 1..{len(values)}")


def _active_alarms(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[Any]:
    kind, count = req.args[0], req.args[1]
    alarms = [a for a in state.active_alarms() if kind == -1 or a.type == kind]
    return alarms[: max(0, count)]


def _macros(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[float | None]:
    return state.read_macros(req.args[0], req.args[1])


def _write_macros(state: MachineState, req: RequestSubpacket, ctx: Context) -> None:
    values = fn.WRITE_MACROS.decode_extra(req, ctx) if fn.WRITE_MACROS.decode_extra else []
    state.read_macros(req.args[0], req.args[1])  # the whole range must exist before anything is written
    for offset, value in enumerate(values):
        state.write_macro(req.args[0] + offset, value, protocol=PROTOCOL)


def _write_macro_double(state: MachineState, req: RequestSubpacket, ctx: Context) -> None:
    value = fn.WRITE_MACRO_DOUBLE.decode_extra(req, ctx) if fn.WRITE_MACRO_DOUBLE.decode_extra else None
    state.write_macro(req.args[0], value, protocol=PROTOCOL)


def _pmc_area(code: int, function: str) -> str:
    area = PMC_AREA_BY_CODE.get(code)
    if area is None:
        raise cnc_error(EW_ATTRIB, function, message=f"PMC address type {code} unknown")
    return area


def _read_pmc(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[int | float]:
    start, end, adr_type, data_type, _ = req.args
    area = _pmc_area(adr_type, "pmc_rdpmcrng")
    try:
        width = PmcType(data_type).width
    except ValueError:
        raise cnc_error(EW_ATTRIB, "pmc_rdpmcrng", message=f"PMC data type {data_type} unknown") from None
    if (end - start + 1) % width:
        raise cnc_error(EW_LENGTH, "pmc_rdpmcrng", message=(
            f"{area}{start}-{area}{end} is not a whole number of {width}-byte elements"))
    return state.read_pmc(area, start, end, data_type)


def _write_pmc(state: MachineState, req: RequestSubpacket, ctx: Context) -> None:
    start, end, adr_type, _data_type, _ = req.args
    area = _pmc_area(adr_type, "pmc_wrpmcrng")
    if end - start + 1 > 32 or len(req.extra) > 32:
        raise cnc_error(EW_LENGTH, "pmc_wrpmcrng",
                        message=f"{end - start + 1} bytes in one write; at most 32")
    data = fn.WRITE_PMC.decode_extra(req, ctx) if fn.WRITE_PMC.decode_extra else b""
    state.write_pmc(area, start, data, protocol=PROTOCOL)


def _params(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[Any]:
    return state.read_params(req.args[0], req.args[1], req.args[2])


def _diag(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[Any]:
    return state.read_diag(req.args[0], req.args[1], req.args[2])


def _clock(state: MachineState, req: RequestSubpacket, ctx: Context) -> Any:
    if req.args[0] not in (fn.CLOCK_DATE, fn.CLOCK_TIME):
        raise cnc_error(EW_NUMBER, "cnc_gettimer", message=f"type {req.args[0]} is not 0 (date) or 1 (time)")
    return state.clock()


def _set_time(state: MachineState, req: RequestSubpacket, ctx: Context) -> None:
    if req.args[0] != fn.CLOCK_TIME:
        raise cnc_error(EW_FUNC, "cnc_settimer", message="only the time form (type 1) is known")
    when = fn.SET_TIME.decode_extra(req, ctx) if fn.SET_TIME.decode_extra else None
    assert when is not None
    state.set_time_of_day(when.hour, when.minute, when.second, protocol=PROTOCOL)


def _spindle_load(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[float]:
    return _per_axis(state.spindle_loads(), req.args[1], "cnc_rdspmeter")


HANDLERS: dict[Function, Handler] = {
    fn.SYSINFO: lambda s, r, c: s.sysinfo(),
    fn.STATINFO: lambda s, r, c: s.status(),
    fn.ALARM_STATUS: lambda s, r, c: s.alarm_status(),
    fn.ALARM_MESSAGES: _active_alarms,
    fn.PROGRAM_NUMBER: lambda s, r, c: s.program_numbers(),
    fn.SEQUENCE_NUMBER: lambda s, r, c: s.sequence_number(),
    fn.EXEC_PROGRAM_NAME: lambda s, r, c: s.exec_program(),
    fn.MAIN_PROGRAM_PATH: lambda s, r, c: s.main_program_path(),
    fn.PROGRAM_DIRECTORY: lambda s, r, c: s.program_directory(r.args[0], r.args[1]),
    fn.ACTUAL_FEED: lambda s, r, c: s.actual_feed(),
    fn.ACTUAL_SPINDLE_SPEED: lambda s, r, c: s.spindle_speed(),
    fn.SPINDLE_LOAD: _spindle_load,
    fn.POSITIONS: _positions,
    fn.AXIS_NAMES: lambda s, r, c: s.axis_names(),
    fn.SPINDLE_NAMES: lambda s, r, c: s.spindle_names(),
    fn.SERVO_METER: lambda s, r, c: s.servo_meter(),
    fn.CONTROLLED_AXES: lambda s, r, c: s.controlled_axes(r.args[0]),
    fn.READ_PARAMS_4: _params,
    fn.READ_PARAMS_8: _params,
    fn.READ_DIAG_4: _diag,
    fn.READ_DIAG_8: _diag,
    fn.READ_MACROS: _macros,
    fn.WRITE_MACROS: _write_macros,
    fn.WRITE_MACRO_DOUBLE: _write_macro_double,
    fn.READ_PMC: _read_pmc,
    fn.WRITE_PMC: _write_pmc,
    fn.READ_CLOCK: _clock,
    fn.SET_TIME: _set_time,
    fn.READ_TIMER: lambda s, r, c: s.timer(r.args[0]),
}


def _function_name(req: RequestSubpacket) -> str:
    function = fn.BY_COMMAND.get((req.cls, req.command))
    return function.name if function else f"0x{req.command:04x}"


def answer_subpacket(state: MachineState, req: RequestSubpacket, faults: FaultPlan | None = None,
                     ctx: Context | None = None) -> ResponseSubpacket:
    """The answer to one request subpacket: data, or an error subpacket with the EW code."""
    ctx = ctx or Context.from_sysinfo(state.sysinfo())
    function = fn.BY_COMMAND.get((req.cls, req.command))
    name = _function_name(req)
    forced = faults.ew_for(req.command, name) if faults else None
    if forced is not None:
        return error_response(req, forced)
    if req.path != 1:
        return error_response(req, EW_PATH)
    if function is None or req.command in state.profile.refused_commands or function not in HANDLERS:
        return error_response(req, EW_FUNC)
    try:
        value = HANDLERS[function](state, req, ctx)
        if function is fn.READ_TIMER and state.profile.timer_little_endian:
            # a 31i-B answers this one little-endian (shared/docs/focas-protocol.md §3.6)
            payload = struct.pack("<ii", value.minutes, value.msec)
            return ResponseSubpacket(req.cls, req.command, 0, 0, payload, req.path)
        return function.response(req, value, ctx)
    except CncError as exc:
        return error_response(req, exc.code)
    except ProtocolError:  # a write whose extra bytes do not match its args
        return error_response(req, EW_LENGTH)
    except ValueError:  # a value the wire cannot carry
        return error_response(req, EW_NUMBER)


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
    commands: Counter[int] = field(default_factory=Counter)

    def describe(self) -> dict[str, Any]:
        return {"connections": self.connections, "refused": self.refused, "open_pdus": self.open_pdus,
                "data_pdus": self.data_pdus, "close_pdus": self.close_pdus, "subpackets": self.subpackets,
                "last_batch": self.last_batch}


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
        finally:
            self._sessions.discard(writer)
            writer.close()
            with contextlib.suppress(Exception):
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
        requests = decode_request_body(body)
        self.stats.data_pdus += 1
        self.stats.subpackets += len(requests)
        self.stats.last_batch = len(requests)
        self.stats.commands.update(req.command for req in requests)
        if self.faults.take_drop():
            writer.transport.abort()
            return "dropped"
        if self.faults.take_garbage():
            writer.write(GARBAGE)
            return "ok"
        answers = [answer_subpacket(self.state, req, self.faults, self.context) for req in requests]
        reply = encode_response(answers, version)
        calls = [(req.command, _function_name(req)) for req in requests]
        if self.faults.take_hang() or self.faults.take_hang_on(calls):
            writer.write(reply[: max(1, len(reply) // 2)])
            await writer.drain()
            return "hang"
        writer.write(reply)
        return "ok"


async def _stay_silent(reader: asyncio.StreamReader) -> None:
    """Hang: keep the socket open, read and ignore, say nothing until the peer gives up (no FIN from us)."""
    while await reader.read(READ_SIZE):
        pass
