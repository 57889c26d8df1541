"""The packed surface's command-id table, its status word, and the primitives every layout shares.

Every response of the surface starts with an i16 status (writes answer nothing else); a non-zero status
becomes the typed CncError of edge.focas.errors, with the seed's own code for the parameter-write lock.
The length helpers here are what makes every decoder refuse a payload of the wrong size the same way.
"""

from __future__ import annotations

import enum
import struct

from edge.focas.errors import EW_OK, EW_PASSWD, AccessDenied, CncError, ProtocolError, cnc_error


class Command(enum.IntEnum):
    """The append-only command-id table. Never renumber, never reuse an id."""

    # --- the seed's ids -----------------------------------------------------------------------------
    RDCNCSTAT = 0x0001  # cnc_rdcncstat: ODBST, 9 x i16
    RDPARAM = 0x0002  # cnc_rdparam: one parameter number
    RDMACRO = 0x0003  # cnc_rdmacro: one macro variable
    RDDIAG = 0x0004  # cnc_rddiag: one diagnosis number
    WRPARAM = 0x0102  # cnc_wrparam: IODBPSD
    WRMACRO = 0x0103  # cnc_wrmacro: ODBM
    WRPMCRNG = 0x0104  # pmc_wrpmcrng: IODBPMC
    RDALMHISTRY = 0x0F1A  # cnc_rdalmhistry: ODBALMHIS
    # --- focas-edge extensions: the 0x4000 block, far from every id the seed (or lmxopcua) uses --------
    SYSINFO = 0x4001  # cnc_sysinfo: ODBSYS
    RDPMCRNG = 0x4002  # pmc_rdpmcrng: IODBPMC, the 0x0104 packet read back
    GETTIME = 0x4003  # cnc_gettime: CNC local date and time
    RDALMMSG = 0x4004  # cnc_rdalmmsg: active alarms with text
    ALARM = 0x4005  # cnc_alarm: alarm status bitfield
    RDPRGNUM = 0x4006  # cnc_rdprgnum: running and main program numbers
    RDSEQNUM = 0x4007  # cnc_rdseqnum: sequence number
    POSITION = 0x4008  # cnc_absolute/machine/relative/distance: one value per axis
    ACTF = 0x4009  # cnc_actf: actual feed
    ACTS = 0x400A  # cnc_acts: actual spindle speed
    RDAXISNAME = 0x400B  # cnc_rdaxisname: axis names
    RDTIMER = 0x400C  # cnc_rdtimer: minutes + milliseconds
    RDZOFS = 0x400D  # cnc_rdzofs: one work-coordinate offset, every axis (IODBZOFS)
    RDGCODE = 0x400E  # cnc_rdgcode: modal G codes of the active block (ODBGCD)
    RDTOOLNUM = 0x400F  # cnc_modal type 108: the T code in use (ODBMDL aux)


# Ids another implementation of the surface uses with a layout we do not know; never assign them.
RESERVED_IDS: dict[int, str] = {0x0105: "cnc_wrunlockparam (lmxopcua; 4-byte password, layout unpublished)"}

FOCAS_NAMES: dict[Command, str] = {
    Command.RDCNCSTAT: "cnc_rdcncstat",
    Command.RDPARAM: "cnc_rdparam",
    Command.RDMACRO: "cnc_rdmacro",
    Command.RDDIAG: "cnc_rddiag",
    Command.WRPARAM: "cnc_wrparam",
    Command.WRMACRO: "cnc_wrmacro",
    Command.WRPMCRNG: "pmc_wrpmcrng",
    Command.RDALMHISTRY: "cnc_rdalmhistry",
    Command.SYSINFO: "cnc_sysinfo",
    Command.RDPMCRNG: "pmc_rdpmcrng",
    Command.GETTIME: "cnc_gettime",
    Command.RDALMMSG: "cnc_rdalmmsg",
    Command.ALARM: "cnc_alarm",
    Command.RDPRGNUM: "cnc_rdprgnum",
    Command.RDSEQNUM: "cnc_rdseqnum",
    Command.POSITION: "cnc_position",
    Command.ACTF: "cnc_actf",
    Command.ACTS: "cnc_acts",
    Command.RDAXISNAME: "cnc_rdaxisname",
    Command.RDTIMER: "cnc_rdtimer",
    Command.RDZOFS: "cnc_rdzofs",
    Command.RDGCODE: "cnc_rdgcode",
    Command.RDTOOLNUM: "cnc_modal",
}


def command_name(command: int) -> str:
    """The FOCAS name of a command id, or its hex form for an id outside the table."""
    try:
        return FOCAS_NAMES[Command(command)]
    except ValueError:
        return f"packed-0x{command:04X}"


# ---- statuses -------------------------------------------------------------------------------------
# The seed's surface reports EW_PASSWD as 11, while fwlib32.h (and the native protocol) has EW_PASSWD = 17
# and EW_PATH = 11. The surface is single-path, so 11 here always means "password/parameter-write lock";
# we accept 17 too, for bridges that pass the vendor library's code through unchanged.
PACKED_EW_PASSWD = 11
_ACCESS_DENIED_STATUSES = frozenset({PACKED_EW_PASSWD, EW_PASSWD})

I16 = struct.Struct("<h")


def status_error(status: int, command: int) -> CncError | None:
    """The typed error for a non-zero status of this surface; None for 0 (good)."""
    if status == EW_OK:
        return None
    function = command_name(command)
    if status in _ACCESS_DENIED_STATUSES:
        return AccessDenied(EW_PASSWD, function, message=(
            f"packed status {status}: parameter-write switch off or CNC not in MDI"))
    return cnc_error(status, function)


def encode_status(status: int) -> bytes:
    """A write response (seed: one i16), and the status prefix of every read response."""
    return I16.pack(status)


def decode_status(payload: bytes, command: int) -> None:
    """Check a write response: exactly one i16 status; raise its typed error when it is not 0."""
    if len(payload) != 2:
        raise ProtocolError(
            f"{command_name(command)}: expected a 2-byte status response, got {len(payload)} bytes"
        )
    _raise_for(I16.unpack(payload)[0], command)


def _raise_for(status: int, command: int) -> None:
    error = status_error(status, command)
    if error is not None:
        raise error


def body_after_status(payload: bytes, command: int) -> bytes:
    """A read response: i16 status, then the body; raise the status's error when it is not 0."""
    if len(payload) < 2:
        raise ProtocolError(
            f"{command_name(command)}: expected at least a 2-byte status, got {len(payload)} bytes"
        )
    _raise_for(I16.unpack_from(payload)[0], command)
    return payload[2:]


def read_response(body: bytes) -> bytes:
    """Server side: a successful read response (status 0, then the body)."""
    return encode_status(EW_OK) + body


def expect_length(body: bytes, length: int, what: str) -> None:
    if len(body) != length:
        raise ProtocolError(f"{what}: expected {length} bytes, got {len(body)}")


def unpack_exact(fmt: struct.Struct, body: bytes, what: str) -> tuple[int, ...]:
    expect_length(body, fmt.size, what)
    return fmt.unpack(body)


def encode_i16(value: int) -> bytes:
    """A one-i16 request (depth, max_count, position kind, timer kind, macro number)."""
    return I16.pack(value)


def decode_i16_request(payload: bytes, what: str) -> int:
    return int(unpack_exact(I16, payload, what)[0])
