"""The simulated CNC's packed-buffer surface: serves a MachineState over TCP or a Unix socket.

Same machine state as the native server, so a write through one protocol is read back through the other.
The rules a real control enforces come from the state (32-byte PMC ceiling -> EW_LENGTH, EW_NUMBER outside
an area, EW_PASSWD while parameter writes are locked); this module only translates: request payload ->
state call -> response payload, using the codecs the client uses (edge.focas.packed).

On this surface EW_PASSWD travels as 11 (seed 002), not fwlib32.h's 17. Unknown command ids answer a
lone i16 EW_FUNC; a payload that does not parse answers EW_LENGTH (EW_ATTRIB for an unknown PMC type_a).
"""

from __future__ import annotations

import logging
import struct
from collections import deque
from collections.abc import Callable

from edge.focas import packed as pk
from edge.focas.errors import EW_ATTRIB, EW_FUNC, EW_LENGTH, CncError, ProtocolError
from edge.focas.model import ParamRecord, PmcType
from edge.focas.packed.endpoint import (
    PackedEndpoint,
    PackedRequest,
    error_answer,
    error_status,
    start_packed_endpoint,
)
from edge.sim.state import MachineState

log = logging.getLogger(__name__)

PROTOCOL = "packed"  # the name writes carry in the machine's write log


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


def _read_pmc(state: MachineState, payload: bytes) -> bytes:
    rng = pk.decode_pmc_range(payload, False, "pmc_rdpmcrng")
    try:
        kind = PmcType(rng.data_type)
    except ValueError:
        return pk.encode_status(EW_ATTRIB)
    if rng.byte_count % kind.width:
        return pk.encode_status(EW_LENGTH)
    values = state.read_pmc(rng.area, rng.start, rng.end, kind)
    data = struct.pack(f"<{len(values)}{kind.struct_code}", *values)
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


def _work_offsets(state: MachineState, payload: bytes) -> bytes:
    number = pk.decode_i16_request(payload, "cnc_rdzofs request")
    return pk.read_response(pk.encode_floats(state.work_offsets(number)))


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
    pk.Command.RDZOFS: _work_offsets,
    pk.Command.RDGCODE: lambda s, _: pk.read_response(pk.encode_modal_g_codes(s.modal_g_codes())),
    pk.Command.RDTOOLNUM: lambda s, _: pk.read_response(pk.encode_int32(s.tool_number())),
}


def answer(state: MachineState, command: int, payload: bytes) -> bytes:
    """The response payload for one request; every failure becomes a status, never an exception."""
    handler = HANDLERS.get(command)
    if handler is None:
        return pk.encode_status(EW_FUNC)
    try:
        return handler(state, payload)
    except (CncError, ProtocolError) as exc:
        return error_answer(command, error_status(exc))


# ---- the server: the shared packed endpoint with this state behind it ---------------------------------
class PackedServer:
    """A running packed-surface server for one MachineState; `address` is what PackedClient takes."""

    def __init__(self, state: MachineState, endpoint: PackedEndpoint) -> None:
        self.state = state
        self.endpoint = endpoint

    @property
    def address(self) -> str:
        return self.endpoint.address

    @property
    def host(self) -> str:
        return self.endpoint.host

    @property
    def port(self) -> int:
        return self.endpoint.port

    @property
    def unix_path(self) -> str:
        return self.endpoint.unix_path

    @property
    def requests(self) -> deque[PackedRequest]:
        """The latest requests (REQUEST_LOG) in arrival order (tests observe chunking and counts here)."""
        return self.endpoint.requests

    @property
    def connections(self) -> int:
        return self.endpoint.connections

    def requests_for(self, command: int) -> list[PackedRequest]:
        return self.endpoint.requests_for(command)

    async def close(self) -> None:
        await self.endpoint.close()

    async def __aenter__(self) -> PackedServer:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()


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

    async def respond(command: int, payload: bytes) -> bytes:
        return answer(state, command, payload)

    endpoint = await start_packed_endpoint(respond, host, port, unix_path=unix_path, name=state.name)
    return PackedServer(state, endpoint)
