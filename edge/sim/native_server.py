"""The simulated CNC's native FOCAS/Ethernet server: the wire protocol over one MachineState.

Byte layouts are not written here: requests are parsed and answers built with the same codecs the
client uses (edge.focas.frame and the function table in edge.focas.functions). For every request
subpacket the server finds the function by (class, command), asks the machine state for the typed
value (or applies the write) and lets the table encode the payload; a CncError from the state becomes
that subpacket's EW code. One answer subpacket per request subpacket, in order, each with its own rc.
`answer_subpacket` does exactly that, step by step: it is the reference.

The server itself answers through AnswerPlans, because a collector asks the same questions every poll
and the reference's per-subpacket work (function lookup, request and answer objects, Decimal-based
scaled encoding) cost a 200-machine fleet a whole core. A plan is compiled once per request subpacket
(its exact bytes) and then only reads the state and encodes: the same handlers and table encoders, with
scaled values, 30i-form records and byte-exact PMC reads encoded directly. The state is read on every
request, as before; tests/unit/test_sim_fastpath.py holds the plans byte-identical to the reference.

Open (0x0101) answers 0x0102, close (0x0201) answers 0x0202 and ends the session, data (0x2101)
answers 0x2102. The header version of answers follows the profile (2, 3 or 4). Unknown commands, and
the parameter/diagnosis form the profile does not have, answer EW_FUNC. Faults (edge.sim.faults) are
applied per request (a data request while an `ew` fault is set is answered by the reference path);
ServerStats counts PDUs so tests can assert "ten items went as one request".
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
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
    RESPONSE_SUB_LAYOUT,
    RESPONSE_SUBPACKET_FIXED,
    U16_LAYOUT,
    Frame,
    FrameDecoder,
    PduType,
    RequestSubpacket,
    ResponseSubpacket,
    decode_request_chunk,
    encode_close_response,
    encode_open_response,
    encode_response,
    request_chunks,
)
from edge.focas.functions import Context, Function, error_response
from edge.focas.model import DIAG_TYPE_CODES, ParamRecord, ParamType, PmcType
from edge.focas.values import RECORD_HEAD_LAYOUT, encode_scaled
from edge.sim.faults import GARBAGE, FaultPlan
from edge.sim.profiles import Profile
from edge.sim.state import MachineState

CLOCK_COMMAND = fn.READ_CLOCK.command

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
    """Diagnosis records carry the diagnosis type codes a real control sends, not the parameter ones."""
    return [replace(record, type=DIAG_TYPE_CODES[ParamType(record.type)])
            for record in state.read_diag(req.args[0], req.args[1], req.args[2])]


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
    fn.TOOL_OFFSETS: lambda s, r, c: s.tool_offsets(r.args[2], r.args[0], r.args[1]),
    fn.OPERATOR_MESSAGES: lambda s, r, c: s.operator_messages(),
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
    forced = faults.ew_for(req.command, name, req.args) if faults else None
    if forced is not None:
        return error_response(req, forced)
    path_state = state.for_path(req.path)
    if path_state is None:
        return error_response(req, EW_PATH)
    state = path_state
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


# ---- the fast path: one compiled answer per request subpacket, byte-identical to answer_subpacket ------
_TIMER_LE = struct.Struct("<ii")
_MAX_PAYLOAD = 0xFFFF - RESPONSE_SUBPACKET_FIXED
_ZERO_SLOT = encode_scaled(0)  # the padding slot of a 30i-form record
# PMC data types whose elements unpack and pack back to the very same bytes (not float: NaN payloads).
_BYTE_EXACT_PMC_TYPES = frozenset({PmcType.BYTE, PmcType.WORD, PmcType.LONG})
SCALED_CACHE_LIMIT = 8192  # remembered scaled encodings (shared by every machine of the process)
PLAN_CACHE_LIMIT = 512  # compiled read shapes per server; a collector polls a few dozen

AnswerSource = Callable[[], bytes]
_scaled_known: dict[tuple[type, object], bytes] = {}


def scaled_bytes(value: float | None) -> bytes:
    """encode_scaled(value), remembered by type and value: macros, feeds and zero slots repeat every poll."""
    key = (value.__class__, value)
    known = _scaled_known.get(key)
    if known is None:
        known = encode_scaled(value)
        if len(_scaled_known) >= SCALED_CACHE_LIMIT:
            _scaled_known.clear()
        _scaled_known[key] = known
    return known


def _scaled_list_bytes(values: Sequence[float | None]) -> bytes:
    """encode_scaled_list(values)."""
    return b"".join(map(scaled_bytes, values))


def _scaled_records_bytes(records: Sequence[ParamRecord], max_axis: int) -> bytes:
    """encode_records(records, max_axis, SlotForm.SCALED): 30i-form records, missing slots zero."""
    parts = []
    for record in records:
        values = record.values
        if len(values) > max_axis:
            raise ValueError(f"record {record.number} has {len(values)} values, max_axis {max_axis}")
        parts.append(RECORD_HEAD_LAYOUT.pack(record.number, record.axis, record.type))
        parts.extend(map(scaled_bytes, values))
        parts.append(_ZERO_SLOT * (max_axis - len(values)))
    return b"".join(parts)


def _direct_encoder(function: Function, ctx: Context) -> Callable[[Any], bytes] | None:
    """A quicker encoder giving the same bytes as the table's, where the table's is the costly kind.

    Matched by the encoder itself, not the function, so a table entry that changes its encoder simply
    falls back to it.
    """
    encoder = function.encode_payload
    if encoder is fn.POSITIONS.encode_payload:  # n x 8-B scaled: macros, positions, loads, meters
        return _scaled_list_bytes
    if encoder is fn.ACTUAL_FEED.encode_payload:  # one 8-B scaled value: feed, spindle speed
        return scaled_bytes
    if encoder in (fn.READ_PARAMS_8.encode_payload, fn.READ_DIAG_8.encode_payload):  # 30i-form records
        max_axis = ctx.max_axis
        return lambda records: _scaled_records_bytes(records, max_axis)
    return None


def _pmc_memory_source(state: MachineState, req: RequestSubpacket) -> AnswerSource | None:
    """A well-formed byte/word/long PMC read: its memory bytes as they are (what unpack-then-pack gives).

    None for any other shape (unknown area or type, partial elements, float types): the generic path
    answers those, with the reference's errors.
    """
    start, end, adr_type, data_type, _ = req.args
    area = PMC_AREA_BY_CODE.get(adr_type)
    if area is None or data_type not in _BYTE_EXACT_PMC_TYPES:
        return None
    width = PmcType(data_type).width
    count = (end - start + 1) // width
    if (end - start + 1) % width or count < 1:
        return None
    last = start + count * width - 1
    return lambda: state.read_pmc_bytes(area, start, last)


def _payload_source(state: MachineState, req: RequestSubpacket, function: Function, ctx: Context) -> AnswerSource:
    """How this request's payload is made on every poll: the reference's handler and encoder, or a
    byte-identical shortcut for the hot ones."""
    handler = HANDLERS[function]
    if function is fn.READ_TIMER and state.profile.timer_little_endian:
        def little_endian_timer() -> bytes:
            value = handler(state, req, ctx)
            return _TIMER_LE.pack(value.minutes, value.msec)

        return little_endian_timer
    if handler is _read_pmc:
        memory = _pmc_memory_source(state, req)
        if memory is not None:
            return memory
    direct = _direct_encoder(function, ctx)
    if direct is not None:
        return lambda: direct(handler(state, req, ctx))
    encode = function.encode_payload
    return lambda: encode(handler(state, req, ctx), req, ctx)


class SubpacketTooLong(ValueError):
    """A payload beyond the u16 length; raised after the whole PDU was worked, as encode_response does."""


def _guarded(req: RequestSubpacket, payload_of: AnswerSource) -> AnswerSource:
    """The encoded answer subpacket: the payload with its header, or the EW code the reference gives for
    the exception (CncError its code, ProtocolError EW_LENGTH, ValueError EW_NUMBER)."""
    cls, path, command = req.cls, req.path, req.command

    def answer() -> bytes:
        try:
            payload = payload_of()
        except CncError as exc:
            return error_response(req, exc.code).encode()
        except ProtocolError:  # a write whose extra bytes do not match its args
            return error_response(req, EW_LENGTH).encode()
        except ValueError:  # a value the wire cannot carry
            return error_response(req, EW_NUMBER).encode()
        size = len(payload)
        if size > _MAX_PAYLOAD:
            raise SubpacketTooLong(f"subpacket payload of {size} bytes does not fit a u16 length")
        return RESPONSE_SUB_LAYOUT.pack(RESPONSE_SUBPACKET_FIXED + size, cls, path, command, 0, 0, b"\x00\x00",
                                   size) + payload

    return answer


def _constant(answer: bytes) -> AnswerSource:
    return lambda: answer


def _answer_source(state: MachineState, req: RequestSubpacket, function: Function | None,
                   ctx: Context) -> AnswerSource:
    """answer_subpacket's decision tree, taken once: path, then function, then the data."""
    path_state = state.for_path(req.path)
    if path_state is None:
        return _constant(error_response(req, EW_PATH).encode())
    state = path_state
    if function is None or req.command in state.profile.refused_commands or function not in HANDLERS:
        return _constant(error_response(req, EW_FUNC).encode())
    return _guarded(req, _payload_source(state, req, function, ctx))


@dataclass(frozen=True, slots=True)
class AnswerPlan:
    """One request subpacket, compiled: what the stats and faults need and how to answer it now."""

    command: int
    name: str  # the table name (or 0x.... for an unknown command), as faults address it
    request: RequestSubpacket
    answer: AnswerSource


def compile_plan(state: MachineState, request: RequestSubpacket, ctx: Context) -> AnswerPlan:
    """The plan answering `request` on `state` from now on (reads nothing but the profile yet)."""
    function = fn.BY_COMMAND.get((request.cls, request.command))
    return AnswerPlan(request.command, _function_name(request), request,
                      _answer_source(state, request, function, ctx))


class AnswerPlans:
    """A machine's compiled answers, by request subpacket bytes (the same few reads every poll).

    Compiling reads nothing that changes while serving except the profile and the Context, and the
    plans are dropped when either is replaced; the state itself is read when a plan answers. Requests
    carrying extra bytes (writes) are compiled each time and not kept: their values rarely repeat.
    """

    def __init__(self, state: MachineState) -> None:
        self.state = state
        self._plans: dict[bytes, AnswerPlan] = {}
        self._compiled_for: tuple[Profile, Context] | None = None

    def for_body(self, body: bytes, ctx: Context) -> list[AnswerPlan]:
        """The plans of a 0x2101 body, in order; ProtocolError for a malformed body."""
        if self._compiled_for is None or self._compiled_for[0] is not self.state.profile \
                or self._compiled_for[1] is not ctx:
            self._plans.clear()
            self._compiled_for = (self.state.profile, ctx)
        plans = self._plans
        result = []
        for chunk in request_chunks(body):
            plan = plans.get(chunk)
            if plan is None:
                plan = self._compile(chunk, ctx)
            result.append(plan)
        return result

    def _compile(self, chunk: bytes, ctx: Context) -> AnswerPlan:
        request = decode_request_chunk(chunk)
        plan = compile_plan(self.state, request, ctx)
        if not request.extra:
            if len(self._plans) >= PLAN_CACHE_LIMIT:
                self._plans.clear()
            self._plans[chunk] = plan
        return plan


def encode_planned_response(plans: Sequence[AnswerPlan], version: int) -> bytes:
    """The 0x2102 PDU answering `plans` now: what encode_response gives for answer_subpacket's answers."""
    parts = [U16_LAYOUT.pack(len(plans))]
    too_long: SubpacketTooLong | None = None
    for plan in plans:
        try:
            parts.append(plan.answer())
        except SubpacketTooLong as exc:  # the reference fails only when encoding, after every handler ran
            too_long = too_long or exc
    if too_long is not None:
        raise too_long
    return Frame(version, PduType.DATA_RESPONSE, b"".join(parts)).encode()


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
        if self.faults.ew:
            answers = [answer_subpacket(self.state, plan.request, self.faults, self.context) for plan in plans]
            return encode_response(answers, version)
        return encode_planned_response(plans, version)

    def _take_hang_on(self, plans: Sequence[AnswerPlan]) -> bool:
        """faults.take_hang_on for this request (skipped when no hang_on is set: it would change nothing)."""
        if not self.faults.hang_on:
            return False
        return self.faults.take_hang_on([(plan.command, plan.name) for plan in plans])


async def _stay_silent(reader: asyncio.StreamReader) -> None:
    """Hang: keep the socket open, read and ignore, say nothing until the peer gives up (no FIN from us)."""
    while await reader.read(READ_SIZE):
        pass
