"""The simulated CNC's fast answer path: one compiled AnswerPlan per request subpacket.

The server answers through AnswerPlans, because a collector asks the same questions every poll
and the reference's per-subpacket work (function lookup, request and answer objects, Decimal-based
scaled encoding) cost a 200-machine fleet a whole core. A plan is compiled once per request subpacket
(its exact bytes) and then only reads the state and encodes: the same handlers and table encoders
(edge.sim.native_handlers), with scaled values, 30i-form records and byte-exact PMC reads encoded
directly. The state is read on every request, as before; tests/unit/sim/test_native_plans.py holds the
plans byte-identical to the reference (answer_subpacket).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from edge.focas import functions as fn
from edge.focas.errors import EW_FUNC, EW_LENGTH, EW_NUMBER, EW_PATH, CncError, ProtocolError
from edge.focas.frame import (
    RESPONSE_SUB_LAYOUT,
    RESPONSE_SUBPACKET_FIXED,
    U16_LAYOUT,
    Frame,
    PduType,
    RequestSubpacket,
    decode_request_chunk,
    request_chunks,
)
from edge.focas.function_entry import Context, Function, error_response
from edge.focas.model import ParamRecord, PmcType
from edge.focas.values import RECORD_HEAD_LAYOUT, encode_scaled
from edge.sim.native_handlers import HANDLERS, PMC_AREA_BY_CODE, function_name, read_pmc
from edge.sim.profiles import Profile
from edge.sim.state import MachineState

_TIMER_LE = struct.Struct("<ii")
_MAX_PAYLOAD = 0xFFFF - RESPONSE_SUBPACKET_FIXED
_ZERO_SLOT = encode_scaled(0)  # the padding slot of a 30i-form record
# PMC data types whose elements unpack and pack back to the very same bytes (not float: NaN payloads).
_BYTE_EXACT_PMC_TYPES = frozenset({PmcType.BYTE, PmcType.WORD, PmcType.LONG})
SCALED_CACHE_LIMIT = 8192  # remembered scaled encodings (shared by every machine of the process)
PLAN_CACHE_LIMIT = 512  # compiled read shapes per server; a collector polls a few dozen
BODY_CACHE_LIMIT = 64  # whole read requests per server; a collector sends a handful of different ones

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
    if handler is read_pmc:
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

    @property
    def kept(self) -> bool:
        """Whether the plan is remembered for its bytes (reads are; writes carry extra bytes and are not)."""
        return not self.request.extra


def compile_plan(state: MachineState, request: RequestSubpacket, ctx: Context) -> AnswerPlan:
    """The plan answering `request` on `state` from now on (reads nothing but the profile yet)."""
    function = fn.BY_COMMAND.get((request.cls, request.command))
    return AnswerPlan(request.command, function_name(request), request,
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
        # whole request bodies of kept plans: a collector sends the same few bodies every poll, and splitting
        # one into its subpackets cost as much as answering three of them
        self._bodies: dict[bytes, list[AnswerPlan]] = {}
        self._compiled_for: tuple[Profile, Context] | None = None

    def for_body(self, body: bytes, ctx: Context) -> list[AnswerPlan]:
        """The plans of a 0x2101 body, in order; ProtocolError for a malformed body."""
        if self._compiled_for is None or self._compiled_for[0] is not self.state.profile \
                or self._compiled_for[1] is not ctx:
            self._plans.clear()
            self._bodies.clear()
            self._compiled_for = (self.state.profile, ctx)
        known = self._bodies.get(body)
        if known is not None:
            return known
        plans = self._plans
        result = []
        for chunk in request_chunks(body):
            plan = plans.get(chunk)
            if plan is None:
                plan = self._compile(chunk, ctx)
            result.append(plan)
        if all(plan.kept for plan in result):
            if len(self._bodies) >= BODY_CACHE_LIMIT:
                self._bodies.clear()
            self._bodies[body] = result
        return result

    def _compile(self, chunk: bytes, ctx: Context) -> AnswerPlan:
        request = decode_request_chunk(chunk)
        plan = compile_plan(self.state, request, ctx)
        if plan.kept:
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


