"""The packed-buffer surface of seeds 000-002: little-endian payload codecs, sans-IO, and their transport.

The surface is a language-neutral encoding that a FOCAS client and a simulator (or a bridge to the vendor
library) speak over IPC. It is *not* the native FOCAS/Ethernet wire format: every integer is little-endian
and each FOCAS call has a stable command id from an append-only table.

Both directions are here (client requests/decoders and the simulator's request decoders/response
encoders), so client and simulator cannot disagree about a layout; every writer is the matching reader
reversed. docs/packed-protocol.md has a byte table for every layout.

Reads defined by this project (the seed only names them) answer ``i16 status`` first, then the body when
status is 0. Writes answer exactly one ``i16 status`` (seed). ODBALMHIS (0x0F1A) answers ``num_alm``
first, negative meaning a CNC error, and its decoder never raises (the seed's empty list); the client reads
it through decode_alarm_history_response, which raises that error instead.

What lives here, by area (this package's ``__all__`` is the codecs' contract; import them from here):

    commands   the command-id table, the status word, the primitives every layout shares
    scaled     numbers as (int32 mantissa, decimals)
    params     IODBPSD: parameters and diagnosis
    macros     ODBM: macro variables
    pmc        IODBPMC: PMC ranges
    alarms     ODBALMHIS and the active alarms
    machine    the small fixed reads: status, sysinfo, clock, positions, timers, G codes ...

and the transport, imported by its own path (never from here, so that importing a codec never pulls in
asyncio):

    frame      the IPC framing (length, command, seq), sans-IO
    client     PackedClient, a CncSession over TCP or a Unix socket (asyncio)
    endpoint   the asyncio listener both servers of the surface sit on (simulator, FOCAS library host)

Rules: the codec modules and frame import only the standard library, each other and edge.focas.errors and
model; client and endpoint sit on top of them. Nothing here imports from outside edge.focas except the
root edge.ConfigError (address parsing in client).
"""

from __future__ import annotations

from edge.focas.packed.alarms import (
    ALMHIS_MAX_DEPTH,
    ALMHIS_MIN_DEPTH,
    LIBRARY_STATUS_OFFSET,
    AlarmHistoryAnswer,
    AlarmHistoryRow,
    alarm_history_status,
    almhis_padding,
    clamp_depth,
    decode_alarm_history,
    decode_alarm_history_request,
    decode_alarm_history_response,
    decode_alarm_messages_response,
    encode_alarm_history,
    encode_alarm_history_error,
    encode_alarm_history_request,
    encode_alarm_history_rows,
    encode_alarm_messages,
    parse_alarm_history,
)
from edge.focas.packed.commands import (
    FOCAS_NAMES,
    PACKED_EW_PASSWD,
    RESERVED_IDS,
    Command,
    command_name,
    decode_i16_request,
    decode_status,
    encode_i16,
    encode_status,
    read_response,
    status_error,
)
from edge.focas.packed.machine import (
    AXIS_NAME_WIDTH,
    G_CODE_WIDTH,
    POSITION_CODES,
    POSITION_KINDS_BY_CODE,
    CncStatus,
    decode_axis_names_response,
    decode_clock_response,
    decode_cncstat,
    decode_cncstat_response,
    decode_float_response,
    decode_floats_response,
    decode_int32_response,
    decode_modal_g_codes_response,
    decode_program_numbers_response,
    decode_sysinfo_response,
    decode_timer_response,
    decode_tool_number_response,
    decode_work_offsets_response,
    encode_axis_names,
    encode_clock,
    encode_cncstat,
    encode_float,
    encode_floats,
    encode_int32,
    encode_modal_g_codes,
    encode_program_numbers,
    encode_sysinfo,
    encode_timer,
)
from edge.focas.packed.macros import (
    ODBM_LENGTH,
    VACANT,
    decode_macro,
    decode_macro_raw,
    decode_macro_read,
    decode_macro_response,
    encode_macro,
    encode_macro_read,
)
from edge.focas.packed.params import (
    PARAM_WIDTHS,
    ParamWrite,
    decode_param_read,
    decode_param_record,
    decode_param_response,
    decode_param_value,
    decode_param_write,
    encode_param_read,
    encode_param_record,
    encode_param_value,
    encode_param_write,
    param_width,
)
from edge.focas.packed.pmc import (
    PMC_AREA_BY_TYPE_A,
    PMC_MAX_WRITE,
    PMC_TYPE_A,
    PmcCodeError,
    PmcRange,
    decode_pmc_range,
    decode_pmc_read_response,
    encode_pmc_range,
    encode_pmc_read,
    encode_pmc_write,
    pmc_type_a,
    pmc_values,
)
from edge.focas.packed.scaled import I32_MAX, I32_MIN, from_scaled, to_scaled

__all__ = [
    "ALMHIS_MAX_DEPTH",
    "ALMHIS_MIN_DEPTH",
    "AXIS_NAME_WIDTH",
    "FOCAS_NAMES",
    "G_CODE_WIDTH",
    "I32_MAX",
    "I32_MIN",
    "LIBRARY_STATUS_OFFSET",
    "ODBM_LENGTH",
    "PACKED_EW_PASSWD",
    "PARAM_WIDTHS",
    "PMC_AREA_BY_TYPE_A",
    "PMC_MAX_WRITE",
    "PMC_TYPE_A",
    "POSITION_CODES",
    "POSITION_KINDS_BY_CODE",
    "RESERVED_IDS",
    "VACANT",
    "AlarmHistoryAnswer",
    "AlarmHistoryRow",
    "CncStatus",
    "Command",
    "ParamWrite",
    "PmcCodeError",
    "PmcRange",
    "alarm_history_status",
    "almhis_padding",
    "clamp_depth",
    "command_name",
    "decode_alarm_history",
    "decode_alarm_history_request",
    "decode_alarm_history_response",
    "decode_alarm_messages_response",
    "decode_axis_names_response",
    "decode_clock_response",
    "decode_cncstat",
    "decode_cncstat_response",
    "decode_float_response",
    "decode_floats_response",
    "decode_i16_request",
    "decode_int32_response",
    "decode_macro",
    "decode_macro_raw",
    "decode_macro_read",
    "decode_macro_response",
    "decode_modal_g_codes_response",
    "decode_param_read",
    "decode_param_record",
    "decode_param_response",
    "decode_param_value",
    "decode_param_write",
    "decode_pmc_range",
    "decode_pmc_read_response",
    "decode_program_numbers_response",
    "decode_status",
    "decode_sysinfo_response",
    "decode_timer_response",
    "decode_tool_number_response",
    "decode_work_offsets_response",
    "encode_alarm_history",
    "encode_alarm_history_error",
    "encode_alarm_history_request",
    "encode_alarm_history_rows",
    "encode_alarm_messages",
    "encode_axis_names",
    "encode_clock",
    "encode_cncstat",
    "encode_float",
    "encode_floats",
    "encode_i16",
    "encode_int32",
    "encode_macro",
    "encode_macro_read",
    "encode_modal_g_codes",
    "encode_param_read",
    "encode_param_record",
    "encode_param_value",
    "encode_param_write",
    "encode_pmc_range",
    "encode_pmc_read",
    "encode_pmc_write",
    "encode_program_numbers",
    "encode_status",
    "encode_sysinfo",
    "encode_timer",
    "from_scaled",
    "param_width",
    "parse_alarm_history",
    "pmc_type_a",
    "pmc_values",
    "read_response",
    "status_error",
    "to_scaled",
]
