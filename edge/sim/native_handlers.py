"""The simulated CNC's native FOCAS answers, one handler per function: the reference answer path.

Byte layouts are not written here: requests are parsed and answers built with the same codecs the
client uses (edge.focas.frame and the function table in edge.focas.functions). For every request
subpacket the server finds the function by (class, command), asks the machine state for the typed
value (or applies the write) and lets the table encode the payload; a CncError from the state becomes
that subpacket's EW code. One answer subpacket per request subpacket, in order, each with its own rc.
`answer_subpacket` does exactly that, step by step: it is the reference (edge.sim.native_plans answers
the same bytes faster; edge.sim.native_server carries them over TCP).

Unknown commands, and the parameter/diagnosis form the profile does not have, answer EW_FUNC; a path
the control does not have answers EW_PATH; an `ew` fault (edge.sim.faults) forces a function's code.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import replace
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
from edge.focas.frame import RequestSubpacket, ResponseSubpacket
from edge.focas.function_entry import Context, Function, error_response
from edge.focas.model import DIAG_TYPE_CODES, ParamType, PmcType
from edge.sim.faults import FaultPlan
from edge.sim.state import MachineState

PROTOCOL = "native"  # the name writes carry in the machine's write log
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


def read_pmc(state: MachineState, req: RequestSubpacket, ctx: Context) -> list[int | float]:
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
    fn.READ_PMC: read_pmc,
    fn.WRITE_PMC: _write_pmc,
    fn.READ_CLOCK: _clock,
    fn.SET_TIME: _set_time,
    fn.READ_TIMER: lambda s, r, c: s.timer(r.args[0]),
    fn.TOOL_OFFSETS: lambda s, r, c: s.tool_offsets(r.args[2], r.args[0], r.args[1]),
    fn.OPERATOR_MESSAGES: lambda s, r, c: s.operator_messages(),
}


def function_name(req: RequestSubpacket) -> str:
    function = fn.BY_COMMAND.get((req.cls, req.command))
    return function.name if function else f"0x{req.command:04x}"


def answer_subpacket(state: MachineState, req: RequestSubpacket, faults: FaultPlan | None = None,
                     ctx: Context | None = None) -> ResponseSubpacket:
    """The answer to one request subpacket: data, or an error subpacket with the EW code."""
    ctx = ctx or Context.from_sysinfo(state.sysinfo())
    function = fn.BY_COMMAND.get((req.cls, req.command))
    name = function_name(req)
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

