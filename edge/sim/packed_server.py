"""The simulated CNC's packed-buffer surface: serves a MachineState over TCP or a Unix socket.

Same machine state as the native server, so a write through one protocol is read back through the other.
The rules a real control enforces come from the state (32-byte PMC ceiling -> EW_LENGTH, EW_NUMBER outside
an area, EW_PASSWD while parameter writes are locked); this module only translates: request payload ->
state call -> response payload, using the codecs the client uses (edge.focas.packed).

On this surface EW_PASSWD travels as 11 (seed 002), not fwlib32.h's 17. Unknown command ids answer a
lone i16 EW_FUNC; a payload that does not parse answers EW_LENGTH (EW_ATTRIB for an unknown PMC type_a).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from edge.focas import packed as pk
from edge.focas.errors import EW_ATTRIB, EW_FUNC, EW_LENGTH, EW_PASSWD, CncError, ProtocolError
from edge.focas.model import ParamRecord, PmcType
from edge.focas.packed_frame import FrameDecoder, PackedFrame
from edge.sim.state import MachineState

log = logging.getLogger(__name__)

PROTOCOL = "packed"  # the name writes carry in the machine's write log
_READ_CHUNK = 65536


def surface_status(error: CncError) -> int:
    """The status this surface sends for a CNC error: EW_PASSWD is 11 here (seed 002)."""
    return pk.PACKED_EW_PASSWD if error.code == EW_PASSWD else error.code


# ---- one handler per command: (state, request payload) -> response payload --------------------------
Handler = Callable[[MachineState, bytes], bytes]


def _status_of(state: MachineState, payload: bytes) -> bytes:
    return pk.read_response(pk.encode_cncstat(pk.CncStatus.from_statinfo(state.status())))


def _record(records: list[ParamRecord], number: int, function: str) -> ParamRecord:
    for record in records:
        if record.number == number:
            return record
    raise CncError(3, function, message=f"number {number} not answered")  # pragma: no cover


def _param(state: MachineState, payload: bytes) -> bytes:
    number, axis = pk.decode_param_read(payload)
    record = _record(state.read_params(number, number, axis), number, "cnc_rdparam")
    return pk.read_response(pk.encode_param_record(record))


def _diag(state: MachineState, payload: bytes) -> bytes:
    number, axis = pk.decode_param_read(payload)
    record = _record(state.read_diag(number, number, axis), number, "cnc_rddiag")
    return pk.read_response(pk.encode_param_record(record))


def _macro(state: MachineState, payload: bytes) -> bytes:
    number = pk.decode_macro_read(payload)
    return pk.read_response(pk.encode_macro(number, state.read_macro(number)))


def _write_param(state: MachineState, payload: bytes) -> bytes:
    request = pk.decode_param_write(payload)
    if not state.param_write_enabled:  # the lock answers before anything else, as on a control
        return pk.encode_status(pk.PACKED_EW_PASSWD)
    spec = state.param_spec(request.number)
    width = pk.param_width(spec.type)
    if len(request.data) != width:
        return pk.encode_status(EW_LENGTH)
    state.write_param(request.number, request.axis, request.value_as(spec.type), protocol=PROTOCOL)
    return pk.encode_status(0)


def _write_macro(state: MachineState, payload: bytes) -> bytes:
    number, value = pk.decode_macro(payload, "cnc_wrmacro")
    state.write_macro(number, value, protocol=PROTOCOL)
    return pk.encode_status(0)


def _write_pmc(state: MachineState, payload: bytes) -> bytes:
    rng = pk.decode_pmc_range(payload, True, "pmc_wrpmcrng")
    if rng.data_type != PmcType.BYTE:
        return pk.encode_status(EW_ATTRIB)
    state.write_pmc(rng.area, rng.start, rng.data, protocol=PROTOCOL)
    return pk.encode_status(0)


_PMC_LE: dict[PmcType, str] = {
    PmcType.BYTE: "B", PmcType.WORD: "h", PmcType.LONG: "i", PmcType.FLOAT: "f", PmcType.DOUBLE: "d",
}


def _read_pmc(state: MachineState, payload: bytes) -> bytes:
    rng = pk.decode_pmc_range(payload, False, "pmc_rdpmcrng")
    try:
        kind = PmcType(rng.data_type)
    except ValueError:
        return pk.encode_status(EW_ATTRIB)
    if rng.byte_count % kind.width:
        return pk.encode_status(EW_LENGTH)
    values = state.read_pmc(rng.area, rng.start, rng.end, kind)
    data = struct.pack(f"<{len(values)}{_PMC_LE[kind]}", *values)
    return pk.read_response(pk.encode_pmc_range(pk.PmcRange(rng.area, kind, rng.start, rng.end, data)))


def _alarm_history(state: MachineState, payload: bytes) -> bytes:
    return pk.encode_alarm_history(state.alarm_history(pk.decode_alarm_history_request(payload)))


def _active_alarms(state: MachineState, payload: bytes) -> bytes:
    max_count = pk.decode_i16_request(payload, "cnc_rdalmmsg request")
    return pk.read_response(pk.encode_alarm_messages(state.active_alarms(max_count)))


def _position(state: MachineState, payload: bytes) -> bytes:
    code = pk.decode_i16_request(payload, "cnc_position request")
    kind = pk.POSITION_KINDS_BY_CODE.get(code)
    if kind is None:
        return pk.encode_status(3)
    return pk.read_response(pk.encode_floats(state.positions(kind)))


def _timer(state: MachineState, payload: bytes) -> bytes:
    kind = pk.decode_i16_request(payload, "cnc_rdtimer request")
    return pk.read_response(pk.encode_timer(state.timer(kind)))


HANDLERS: dict[int, Handler] = {
    pk.Command.RDCNCSTAT: _status_of,
    pk.Command.RDPARAM: _param,
    pk.Command.RDMACRO: _macro,
    pk.Command.RDDIAG: _diag,
    pk.Command.WRPARAM: _write_param,
    pk.Command.WRMACRO: _write_macro,
    pk.Command.WRPMCRNG: _write_pmc,
    pk.Command.RDALMHISTRY: _alarm_history,
    pk.Command.SYSINFO: lambda s, _: pk.read_response(pk.encode_sysinfo(s.sysinfo())),
    pk.Command.RDPMCRNG: _read_pmc,
    pk.Command.GETTIME: lambda s, _: pk.read_response(pk.encode_clock(s.clock())),
    pk.Command.RDALMMSG: _active_alarms,
    pk.Command.ALARM: lambda s, _: pk.read_response(pk.encode_int32(s.alarm_status())),
    pk.Command.RDPRGNUM: lambda s, _: pk.read_response(pk.encode_program_numbers(s.program_numbers())),
    pk.Command.RDSEQNUM: lambda s, _: pk.read_response(pk.encode_int32(s.sequence_number())),
    pk.Command.POSITION: _position,
    pk.Command.ACTF: lambda s, _: pk.read_response(pk.encode_float(s.actual_feed())),
    pk.Command.ACTS: lambda s, _: pk.read_response(pk.encode_float(s.spindle_speed())),
    pk.Command.RDAXISNAME: lambda s, _: pk.read_response(pk.encode_axis_names(s.axis_names())),
    pk.Command.RDTIMER: _timer,
}


def answer(state: MachineState, command: int, payload: bytes) -> bytes:
    """The response payload for one request; every failure becomes a status, never an exception."""
    handler = HANDLERS.get(command)
    if handler is None:
        return pk.encode_status(EW_FUNC)
    status: int
    try:
        return handler(state, payload)
    except CncError as exc:
        status = surface_status(exc)
    except pk.PmcCodeError:
        status = EW_ATTRIB
    except ProtocolError:
        status = EW_LENGTH
    if command == pk.Command.RDALMHISTRY:
        return pk.encode_alarm_history_error(status)
    return pk.encode_status(status)


# ---- the server ---------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class PackedRequest:
    """One request as the server saw it (tests observe chunking and counts here)."""

    command: int
    payload: bytes


@dataclass(eq=False)
class PackedServer:
    """A running packed-surface server; `address` is what PackedClient takes."""

    state: MachineState
    server: asyncio.Server
    host: str = ""
    port: int = 0
    unix_path: str = ""
    requests: list[PackedRequest] = field(default_factory=list)
    _sessions: dict[asyncio.Task[None], asyncio.StreamWriter] = field(default_factory=dict)

    @property
    def address(self) -> str:
        if self.unix_path:
            return f"unix:{self.unix_path}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp:{host}:{self.port}"

    @property
    def connections(self) -> int:
        """Client connections now open."""
        return len(self._sessions)

    def requests_for(self, command: int) -> list[PackedRequest]:
        return [r for r in self.requests if r.command == command]

    async def close(self) -> None:
        """Stop listening and end every open session (the server does not wait for clients to hang up)."""
        self.server.close()
        for writer in self._sessions.values():
            writer.close()  # the session's read then ends and its task returns
        await asyncio.gather(*self._sessions, return_exceptions=True)
        await self.server.wait_closed()
        if self.unix_path:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.unix_path)

    async def __aenter__(self) -> PackedServer:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._sessions[task] = writer
        try:
            await self._session(reader, writer)
        finally:
            self._sessions.pop(task, None)

    async def _session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername") or self.address
        decoder = FrameDecoder()
        try:
            while data := await reader.read(_READ_CHUNK):
                for frame in decoder.feed(data):
                    self.requests.append(PackedRequest(frame.command, frame.payload))
                    reply = answer(self.state, frame.command, frame.payload)
                    writer.write(PackedFrame(frame.command, frame.seq, reply).encode())
                await writer.drain()
        except ProtocolError as exc:
            log.warning("packed client sent a malformed frame peer=%s machine=%s error=%s",
                        peer, self.state.name, exc)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()


async def start_packed_server(
    state: MachineState,
    host: str = "127.0.0.1",
    port: int = 0,
    *,
    unix_path: str | None = None,
) -> PackedServer:
    """Serve `state` on host:port (port 0 = any free port) or, given unix_path, on that Unix socket.

    Call from the event loop that should run it; `await handle.close()` stops it.
    """
    handle: PackedServer
    if unix_path:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(unix_path)
        server = await asyncio.start_unix_server(lambda r, w: handle._serve(r, w), path=unix_path)
        handle = PackedServer(state, server, unix_path=unix_path)
    else:
        server = await asyncio.start_server(lambda r, w: handle._serve(r, w), host, port)
        bound = server.sockets[0].getsockname()
        handle = PackedServer(state, server, host=host, port=int(bound[1]))
    log.info("packed surface serving machine=%s address=%s", state.name, handle.address)
    return handle
