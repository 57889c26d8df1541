"""The `packed` transport: a CncSession speaking the packed-buffer surface over TCP or a Unix socket.

Same high-level API as the native transport (reads via batch(), writes, bit read-modify-write, PMC
chunking all come from CncSession). A batch sends one request per command needed, pipelined in windows,
and reads the answers in order; each item gets its value or its own error. Items the surface has no
command for answer NotSupported without touching the wire.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from edge import ConfigError
from edge.focas import items as it
from edge.focas import packed as pk
from edge.focas.errors import ConnectionLost, FocasError, NotSupported, OutOfRange, ProtocolError
from edge.focas.model import Capabilities, ParamRecord, SysInfo
from edge.focas.packed.frame import FrameDecoder, PackedFrame
from edge.focas.session import CncSession, ItemResult

# Requests in flight before the client stops to read answers (keeps both socket buffers small).
PIPELINE_WINDOW = 64
_READ_CHUNK = 65536


@dataclass(frozen=True, slots=True)
class PackedAddress:
    """Where a packed-surface server listens: a TCP host and port, or a Unix socket path."""

    host: str = ""
    port: int = 0
    path: str = ""

    @property
    def is_unix(self) -> bool:
        return bool(self.path)

    def __str__(self) -> str:
        if self.is_unix:
            return f"unix:{self.path}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp:{host}:{self.port}"


# The packed surface has no registered port; 18193 sits beside native FOCAS's 8193 without colliding with
# a simulated fleet's consecutive native ports (8193, 8194, ...).
DEFAULT_PORT = 18193
_HOST_PORT = re.compile(r"^(?:\[(?P<v6>[^\]]+)\]|(?P<host>[^:\[\]]+))(?::(?P<port>\d+))?$")


def parse_packed_address(address: str) -> PackedAddress:
    """`tcp:HOST[:PORT]`, `HOST[:PORT]` (IPv6 as `[::1]:PORT`) or `unix:/PATH`; else ConfigError.

    Without a port, DEFAULT_PORT (18193).
    """
    text = address.strip()
    if text.startswith("unix:"):
        path = text[len("unix:") :]
        if not path:
            raise ConfigError([f"{address!r}: expected unix:/PATH, the path is empty"], "packed address")
        return PackedAddress(path=path)
    if text.startswith("tcp:"):
        text = text[len("tcp:") :]
    match = _HOST_PORT.match(text)
    if match is None:
        raise ConfigError(
            [f"{address!r}: expected tcp:HOST:PORT, HOST:PORT or unix:/PATH"], "packed address"
        )
    port = int(match["port"]) if match["port"] else DEFAULT_PORT
    if not 1 <= port <= 65535:
        raise ConfigError([f"{address!r}: port {port} is not 1..65535"], "packed address")
    return PackedAddress(host=match["v6"] or match["host"], port=port)


# ---- how each read item maps onto commands --------------------------------------------------------
Request = tuple[int, bytes]


@dataclass(frozen=True, slots=True)
class ItemPlan:
    """The requests one item needs and how their response payloads become the item's value."""

    requests: list[Request]
    combine: Callable[[list[bytes]], Any]


def _single(command: int, payload: bytes, decode: Callable[[bytes], Any]) -> ItemPlan:
    return ItemPlan([(command, payload)], lambda answers: decode(answers[0]))


def _records(command: pk.Command, first: int, last: int, axis: int) -> ItemPlan:
    """One request per number; a range keeps the numbers the CNC has, a single number raises."""
    numbers = range(first, last + 1)

    def combine(answers: list[bytes]) -> list[ParamRecord]:
        records: list[ParamRecord] = []
        missing: OutOfRange | None = None
        for answer in answers:
            try:
                records.append(pk.decode_param_response(answer, command))
            except OutOfRange as exc:
                missing = missing or exc
        if not records and missing is not None:
            raise missing
        return records

    if last < first:
        raise OutOfRange(3, pk.command_name(command), message=f"range {first}..{last} is empty")
    return ItemPlan([(command, pk.encode_param_read(n, axis)) for n in numbers], combine)


def _macros(first: int, last: int) -> ItemPlan:
    if last < first:
        raise OutOfRange(3, "cnc_rdmacro", message=f"range #{first}..#{last} is empty")
    return ItemPlan(
        [(pk.Command.RDMACRO, pk.encode_macro_read(n)) for n in range(first, last + 1)],
        lambda answers: [pk.decode_macro_response(a)[1] for a in answers],
    )


def _pmc(item: it.ReadPmc) -> ItemPlan:
    request = pk.encode_pmc_read(item.area, item.start, item.end, item.data_type)

    def decode(answer: bytes) -> list[int | float]:
        rng = pk.decode_pmc_read_response(answer)
        return pk.pmc_values(rng.data_type, rng.data)

    return _single(pk.Command.RDPMCRNG, request, decode)


def _positions(kind: str) -> ItemPlan:
    code = pk.POSITION_CODES.get(kind)
    if code is None:
        known = ", ".join(pk.POSITION_CODES)
        raise OutOfRange(4, "cnc_position", message=f"position kind {kind!r} is not one of {known}")
    return _single(pk.Command.POSITION, pk.encode_i16(code),
                   lambda a: pk.decode_floats_response(a, pk.Command.POSITION))


def plan_item(item: it.ReadItem) -> ItemPlan:
    """The wire plan for one read item; NotSupported when the surface has no command for it."""
    C = pk.Command
    match item:
        case it.ReadSysInfo():
            return _single(C.SYSINFO, b"", pk.decode_sysinfo_response)
        case it.ReadStatus():
            return _single(C.RDCNCSTAT, b"", lambda a: pk.decode_cncstat_response(a).to_statinfo())
        case it.ReadAlarmStatus():
            return _single(C.ALARM, b"", lambda a: pk.decode_int32_response(a, C.ALARM))
        case it.ReadActiveAlarms(max_count=max_count):
            return _single(C.RDALMMSG, pk.encode_i16(max_count), pk.decode_alarm_messages_response)
        case it.ReadProgramNumber():
            return _single(C.RDPRGNUM, b"", pk.decode_program_numbers_response)
        case it.ReadSequenceNumber():
            return _single(C.RDSEQNUM, b"", lambda a: pk.decode_int32_response(a, C.RDSEQNUM))
        case it.ReadFeed():
            return _single(C.ACTF, b"", lambda a: pk.decode_float_response(a, C.ACTF))
        case it.ReadSpindleSpeed():
            return _single(C.ACTS, b"", lambda a: pk.decode_float_response(a, C.ACTS))
        case it.ReadPositions(kind=kind):
            return _positions(kind)
        case it.ReadAxisNames():
            return _single(C.RDAXISNAME, b"", pk.decode_axis_names_response)
        case it.ReadParams(first=first, last=last, axis=axis):
            return _records(C.RDPARAM, first, last, axis)
        case it.ReadDiag(first=first, last=last, axis=axis):
            return _records(C.RDDIAG, first, last, axis)
        case it.ReadMacros(first=first, last=last):
            return _macros(first, last)
        case it.ReadPmc():
            return _pmc(item)
        case it.ReadClock():
            return _single(C.GETTIME, b"", pk.decode_clock_response)
        case it.ReadTimer(kind=kind):
            return _single(C.RDTIMER, pk.encode_i16(kind), pk.decode_timer_response)
        case it.ReadModalGCodes():
            return _single(C.RDGCODE, b"", pk.decode_modal_g_codes_response)
        case it.ReadToolNumber():
            return _single(C.RDTOOLNUM, b"", pk.decode_tool_number_response)
        case it.ReadWorkOffsets(number=number):
            return _single(C.RDZOFS, pk.encode_i16(number), pk.decode_work_offsets_response)
        case it.ReadAlarmHistory(depth=depth):
            return _single(C.RDALMHISTRY, pk.encode_alarm_history_request(depth),
                           pk.decode_alarm_history_response)
    raise NotSupported(item.operation, "the packed surface has no command id for it")


SUPPORTED_READS: frozenset[str] = frozenset({
    "ReadSysInfo", "ReadStatus", "ReadAlarmStatus", "ReadActiveAlarms", "ReadProgramNumber",
    "ReadSequenceNumber", "ReadFeed", "ReadSpindleSpeed", "ReadPositions", "ReadAxisNames", "ReadParams",
    "ReadDiag", "ReadMacros", "ReadPmc", "ReadClock", "ReadTimer", "ReadAlarmHistory", "ReadWorkOffsets",
    "ReadModalGCodes", "ReadToolNumber",
})
SUPPORTED_WRITES: frozenset[str] = frozenset({"write_macro", "write_pmc", "write_param"})


class PackedClient(CncSession):
    """`async with PackedClient("unix:/run/cnc1.sock") as cnc: await cnc.batch([...])`."""

    transport = "packed"

    def __init__(
        self,
        address: str,
        *,
        timeout: float = 5.0,
        connect_timeout: float = 5.0,
        backoff_initial: float = 0.5,
        backoff_max: float = 30.0,
    ) -> None:
        super().__init__(timeout=timeout, connect_timeout=connect_timeout,
                         backoff_initial=backoff_initial, backoff_max=backoff_max)
        self.address = parse_packed_address(address)
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._decoder = FrameDecoder()
        self._pending: deque[PackedFrame] = deque()
        self._seq = 0

    def describe(self) -> str:
        return f"packed {self.address}"

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(self.transport, SUPPORTED_READS | SUPPORTED_WRITES)

    # ---- connection ---------------------------------------------------------------------------------
    async def _open(self) -> SysInfo:
        await self._close()
        if self.address.is_unix:
            self._reader, self._writer = await asyncio.open_unix_connection(self.address.path)
        else:
            self._reader, self._writer = await asyncio.open_connection(self.address.host, self.address.port)
        (answer,) = await self._exchange([(pk.Command.SYSINFO, b"")])
        return pk.decode_sysinfo_response(answer)

    async def _close(self) -> None:
        writer, self._writer, self._reader = self._writer, None, None
        self._decoder = FrameDecoder()
        self._pending.clear()
        if writer is None:
            return
        with contextlib.suppress(Exception):
            writer.close()
            await asyncio.wait_for(writer.wait_closed(), 1.0)

    # ---- request/response ---------------------------------------------------------------------------
    async def _exchange(self, requests: Sequence[Request]) -> list[bytes]:
        """Send requests in pipelined windows; return the response payloads in request order."""
        answers: list[bytes] = []
        for at in range(0, len(requests), PIPELINE_WINDOW):
            window = requests[at : at + PIPELINE_WINDOW]
            sent = [self._send(command, payload) for command, payload in window]
            await self._stream_writer().drain()
            for command, seq in sent:
                frame = await self._receive()
                if frame.command != command or frame.seq != seq:
                    raise ProtocolError(
                        f"{self.describe()}: expected the answer to command 0x{command:04X} seq {seq}, "
                        f"got command 0x{frame.command:04X} seq {frame.seq}"
                    )
                answers.append(frame.payload)
        return answers

    def _send(self, command: int, payload: bytes) -> tuple[int, int]:
        self._seq = (self._seq + 1) & 0xFFFF
        self._stream_writer().write(PackedFrame(command, self._seq, payload).encode())
        return command, self._seq

    async def _receive(self) -> PackedFrame:
        reader = self._reader
        if reader is None:
            raise ConnectionLost(f"{self.describe()}: not connected")
        while not self._pending:
            data = await reader.read(_READ_CHUNK)
            if not data:
                raise ConnectionLost(f"{self.describe()}: the server closed the connection")
            self._pending.extend(self._decoder.feed(data))
        return self._pending.popleft()

    def _stream_writer(self) -> asyncio.StreamWriter:
        if self._writer is None:
            raise ConnectionLost(f"{self.describe()}: not connected")
        return self._writer

    async def _call(self, command: int, payload: bytes) -> bytes:
        (answer,) = await self._exchange([(command, payload)])
        return answer

    # ---- transport hooks ----------------------------------------------------------------------------
    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        plans: list[ItemPlan | FocasError] = []
        for item in items:
            try:
                plans.append(plan_item(item))
            except FocasError as exc:
                plans.append(exc)
        requests = [r for plan in plans if isinstance(plan, ItemPlan) for r in plan.requests]
        answers = await self._exchange(requests)
        results: list[ItemResult] = []
        at = 0
        for plan in plans:
            if isinstance(plan, FocasError):
                results.append(plan)
                continue
            mine = answers[at : at + len(plan.requests)]
            at += len(plan.requests)
            try:
                results.append(plan.combine(mine))
            except FocasError as exc:
                results.append(exc)
        return results

    async def _write_macro(self, number: int, value: float) -> None:
        answer = await self._call(pk.Command.WRMACRO, pk.encode_macro(number, value))
        pk.decode_status(answer, pk.Command.WRMACRO)

    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:
        answer = await self._call(pk.Command.WRPMCRNG, pk.encode_pmc_write(area, start, data))
        pk.decode_status(answer, pk.Command.WRPMCRNG)

    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None:
        answer = await self._call(pk.Command.WRPARAM, pk.encode_param_write(number, axis, ptype, value))
        pk.decode_status(answer, pk.Command.WRPARAM)
