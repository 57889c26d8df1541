"""The native FOCAS/Ethernet client: an asyncio shell around the sans-IO codecs.

One TCP connection carries the data session (open PDU payload 00 02). A batch of read items goes out as
ONE 0x2101 request with one subpacket per call (the clock takes two) and comes back as one 0x2102 answer;
each item's CNC error becomes that item's result. Only when a batch needs more than `max_subpackets`
subpackets is it split over several PDUs (never splitting one item). Timeouts, reconnect with backoff,
serialisation of requests and write rules live in CncSession.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import date, datetime
from typing import cast

from edge.focas import functions as fn
from edge.focas import items as it
from edge.focas.errors import (
    ConnectionLost,
    FocasError,
    NotSupported,
    OutOfRange,
    ProtocolError,
    cnc_error,
)
from edge.focas.frame import (
    Answer,
    AnswerMemo,
    AnswerSplitter,
    Echo,
    Frame,
    FrameDecoder,
    PduType,
    RequestSubpacket,
    ResponseSubpacket,
    decode_response_body,
    encode_close_request,
    encode_open_request,
    encode_request,
    intern_ints,
    slot_getter,
)
from edge.focas.function_entry import Context, Function, PayloadDecoder
from edge.focas.model import Capabilities, SysInfo
from edge.focas.native import (
    SUPPORTED_ITEMS,
    ItemPlan,
    clock_value,
    combine_clock,
    first_value,
    item_value,
    shared_plan_item,
)
from edge.focas.session import CncSession, ItemResult
from edge.focas.values import encode_scaled

log = logging.getLogger(__name__)

DEFAULT_PORT = 8193
# HslCommunication sends up to 10 subpackets per PDU and pyfanuc 9; no public source states a limit. 32 keeps
# a typical poll in one PDU while bounding the answer (32 x 30i parameter records = 8.7 KB).
MAX_SUBPACKETS = 32
CLOSE_TIMEOUT = 1.0
WRITE_OPERATIONS = frozenset({"write_macro", "write_pmc", "set_clock"})
PREPARED_CACHE_SIZE = 16  # a poller repeats one or a few item tuples (one per combination of due groups)


class FrameStream(asyncio.Protocol):
    """The TCP connection as a stream of whole frames: bytes are decoded as they arrive (no stream
    reader in between), and the one task waiting for an answer is woken when a frame is complete."""

    def __init__(self, peer: str) -> None:
        self.peer = peer
        self.transport: asyncio.Transport | None = None
        self._decoder = FrameDecoder()
        # A list, not a deque: it holds one answer at a time (an empty deque is ~0.6 kB a session).
        self._frames: list[Frame] = []
        self.frames = self._frames  # complete frames not taken yet (the request path pops them itself)
        self._waiter: asyncio.Future[None] | None = None
        self._error: ProtocolError | None = None
        self._lost: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)  # uvloop's is one, but not a subclass

    def data_received(self, data: bytes) -> None:
        try:
            self._frames.extend(self._decoder.feed(data))
        except ProtocolError as exc:
            self._error = ProtocolError(f"{self.peer}: {exc}")
        self._wake()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self._lost.done():
            self._lost.set_result(None)
        self._wake()

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None:
            self._waiter = None
            if not waiter.done():
                waiter.set_result(None)

    def send(self, data: bytes) -> None:
        if self.transport is None or self._lost.done():
            raise ConnectionLost(f"{self.peer}: not connected")
        self.transport.write(data)

    async def next_frame(self) -> Frame:
        while not self._frames:
            await self.arrival()
        return self._frames.pop(0)

    def arrival(self) -> asyncio.Future[None]:
        """A future done when the next bytes arrive or the connection ends (awaited directly by the request
        path: no coroutine of its own); raises at once if the stream is broken."""
        if self._error is not None:
            raise self._error
        if self._lost.done():
            raise ConnectionLost(f"{self.peer}: peer closed the connection "
                                 f"({self._decoder.buffered} bytes of a frame pending)")
        waiter = self._waiter = self._lost.get_loop().create_future()
        return waiter

    def clear(self) -> None:
        """Forget frames nobody waits for any more (a new session starts)."""
        self._frames.clear()

    async def close(self, timeout: float) -> None:
        if self.transport is not None:
            self.transport.close()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout):
                await asyncio.shield(self._lost)


SingleCall = tuple[PayloadDecoder, RequestSubpacket, str]  # (payload decoder, its request, the function's name)


@dataclass(frozen=True, slots=True)
class PduLayout:
    """One request PDU of a batch, encoded, with the items it serves: the same for every session that asks
    the same item plans (plans are shared too), so machines polling alike hold one copy."""

    data: bytes
    plans: tuple[ItemPlan, ...]  # per entry (an item of the PDU), in subpacket order
    indices: tuple[int, ...]  # per entry, its index in the batch
    starts: tuple[int, ...]  # per entry, the index of its first answer subpacket
    single: tuple[SingleCall | None, ...]  # per entry: its one call, when that call's value is the item's
    owners: tuple[int, ...]  # per request subpacket, the entry it serves
    echoes: tuple[Echo, ...]  # per request subpacket, what its answer echoes


LAYOUTS_LIMIT = 4096  # distinct batches of plans kept to share; a fleet of a few models needs a few dozen
_LAYOUTS: dict[tuple[int, ...], tuple[PduLayout, ...]] = {}


class SessionValues:
    """What a session last got for each item it asks, shared by every batch it repeats (a poller's tick
    shapes overlap: most items are in all of them), so each item's last answer and value are held once.

    A value slot is one item plan (its k-th occurrence in a batch takes the plan's k-th slot); its calls
    take consecutive slots of `answers`. `stale` holds the value slots whose value is an error (decoded
    again on every answer)."""

    __slots__ = ("answers", "first_piece", "plans", "stale", "values")

    def __init__(self) -> None:
        self.answers = AnswerMemo()
        self.values: list[ItemResult] = []
        self.plans: list[ItemPlan] = []  # per value slot
        self.first_piece: list[int] = []  # per value slot, its first slot in `answers`
        self.stale: set[int] = set()

    def slots_for(self, plans: Sequence[ItemPlan]) -> list[int]:
        """Per plan of a batch, its value slot (new slots for plans, or occurrences, not seen before)."""
        known: dict[int, list[int]] = {}
        for slot, plan in enumerate(self.plans):
            known.setdefault(id(plan), []).append(slot)
        used: dict[int, int] = {}
        slots = []
        for plan in plans:
            nth = used[id(plan)] = used.get(id(plan), -1) + 1
            mine = known.get(id(plan), [])
            if nth < len(mine):
                slots.append(mine[nth])
                continue
            slots.append(len(self.plans))
            self.plans.append(plan)
            self.values.append(None)
            self.first_piece.append(self.answers.allocate(len(plan.calls)).start)
        return slots

    def pieces_of(self, slots: Sequence[int]) -> tuple[int, ...]:
        """The answer slots of these value slots' calls, in subpacket order."""
        return tuple(first + call for slot in slots
                     for first in (self.first_piece[slot],) for call in range(len(self.plans[slot].calls)))


@dataclass(frozen=True, slots=True)
class PreparedPdu:
    """One request PDU of a batch as this session sends it: the shared layout, and where its answers and values
    live in the session's SessionValues."""

    layout: PduLayout
    splitter: AnswerSplitter | None  # None: nothing asked (every entry's plan is its error)
    slots: tuple[int, ...]  # per entry, its value slot


@dataclass(frozen=True, slots=True)
class PreparedBatch:
    """A batch a caller repeats: its PDUs, and where each item's value from the last answers is kept.

    Decoding is a pure function of (answer, request, context), so an item none of whose answer
    subpackets moved keeps its value, the very same object, without decoding (most reads of a poll tick
    do not change), and a caller can tell "unchanged" by identity, across batches too (an item's value is
    kept once per session). An item whose value is an error is decoded again every time."""

    items: Sequence[it.ReadItem]
    context: Context
    memo: SessionValues
    pdus: tuple[PreparedPdu, ...]
    results: Callable[[Sequence[ItemResult]], tuple[ItemResult, ...]]  # the memo's values -> the batch's, in order


class FocasClient(CncSession):
    """`async with FocasClient("10.0.0.5") as cnc: await cnc.batch([...])` over native FOCAS/Ethernet."""

    transport = "focas"

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, timeout: float = 5.0,
                 connect_timeout: float = 5.0, path: int = 1, max_subpackets: int = MAX_SUBPACKETS,
                 backoff_initial: float = 0.5, backoff_max: float = 30.0) -> None:
        super().__init__(timeout=timeout, connect_timeout=connect_timeout,
                         backoff_initial=backoff_initial, backoff_max=backoff_max)
        if max_subpackets < 2:
            raise ValueError("max_subpackets must be at least 2 (the clock takes two)")
        self.host = host
        self.port = port
        self.path = path
        self.max_subpackets = max_subpackets
        self.context = Context()
        self.pdus_sent = 0
        self._stream: FrameStream | None = None
        self._in_flight = False
        self._prepared: dict[int, PreparedBatch] = {}
        self._memo = SessionValues()  # for the batches of _prepared, all of this context

    def describe(self) -> str:
        return f"focas://{self.host}:{self.port}"

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(self.transport, SUPPORTED_ITEMS | WRITE_OPERATIONS)

    # ---- session hooks ----------------------------------------------------------------------------------
    async def _open(self) -> SysInfo:
        await self._close()
        loop = asyncio.get_running_loop()
        peer = self.describe()
        _, self._stream = await loop.create_connection(lambda: FrameStream(peer), self.host, self.port)
        self._in_flight = False
        await self._roundtrip(encode_open_request(), PduType.OPEN_RESPONSE, "open")
        self.context = Context()
        request = fn.SYSINFO.request(path=self.path)
        (answer,) = await self._exchange([request])
        info = fn.SYSINFO.decode_response(answer, request, self.context)
        if not isinstance(info, SysInfo):  # pragma: no cover - the table guarantees it
            raise ProtocolError(f"sysinfo decoded to {type(info).__name__}")
        self.context = Context.from_sysinfo(info)
        log.info("connected peer=%s cnc=%s max_axis=%d slots=%d", self.describe(), info.model_name,
                 info.max_axis, int(self.context.slot_form))
        return info

    async def _close(self) -> None:
        stream, self._stream = self._stream, None
        if stream is None:
            return
        healthy = not self._in_flight
        self._in_flight = False
        try:
            if healthy:
                async with asyncio.timeout(CLOSE_TIMEOUT):
                    await self._say_goodbye(stream)
        except Exception as exc:  # closing must never raise
            log.debug("close PDU not acknowledged peer=%s error=%r", self.describe(), exc)
        with contextlib.suppress(Exception):
            await stream.close(CLOSE_TIMEOUT)

    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        prepared = self._prepare(items)
        context = self.context
        memo = prepared.memo
        values, stale = memo.values, memo.stale
        for pdu in prepared.pdus:
            splitter, slots = pdu.splitter, pdu.slots
            body = b""
            answers: Sequence[Answer | None]
            if splitter is not None:
                frame = await self._roundtrip(pdu.layout.data, PduType.DATA_RESPONSE, "data request")
                body = frame.body
                try:
                    answers, moved = splitter.split(body)
                except ProtocolError as exc:
                    raise ProtocolError(f"{self.describe()}: {exc}") from None
            else:  # nothing asked: every item's plan is its error
                answers, moved = (), None
            todo: Iterable[int]
            if moved is None:
                todo = range(len(slots))
            elif moved:
                owners = pdu.layout.owners
                todo = {owners[i] for i in moved}  # (a map of owners.__getitem__ is twice as slow: a slot wrapper)
                if stale:
                    todo.update(entry for entry, slot in enumerate(slots) if slot in stale)
            elif stale and not stale.isdisjoint(slots):
                todo = [entry for entry, slot in enumerate(slots) if slot in stale]
            else:
                continue
            layout = pdu.layout
            starts, plans, single = layout.starts, layout.plans, layout.single
            value: ItemResult
            for entry in todo:
                plan, start, call = plans[entry], starts[entry], single[entry]
                if call is None:
                    got = _answered(answers, splitter, body, start, len(plan.calls))
                    clock = clock_value(*got) if plan.combine is combine_clock else None  # one decode, not three
                    value = item_value(plan, got, 0, context) if clock is None else clock
                else:  # the common item, one call whose value is the item's: without item_value's loop
                    answer = answers[start] if answers else None
                    if answer is None:  # not moved, decoded again (its value was an error)
                        answer = cast(AnswerSplitter, splitter).answer(body, start)
                    decode, request, name = call
                    rc, detail, payload = answer  # native.call_value, inline (every moved item of a tick)
                    if rc:
                        value = cnc_error(rc, name, detail)
                    else:
                        try:
                            value = decode(payload, request, context)
                        except FocasError as exc:
                            value = exc
                slot = slots[entry]
                if isinstance(value, FocasError):
                    stale.add(slot)
                else:
                    stale.discard(slot)
                    # An equal value (the item asked in another batch, or its bytes moved but not its value)
                    # is handed back as the object kept: "unchanged" stays an identity check.
                    if values[slot] == value:
                        value = values[slot]
                values[slot] = value
        return list(prepared.results(values))

    async def _write_macro(self, number: int, value: float) -> None:
        """cmd 0x16 with an exact decimal; cmd 0xa8 (IEEE double) only when no i32 mantissa can carry it."""
        try:
            request = fn.WRITE_MACROS.request(number, number, extra=encode_scaled(value), path=self.path)
            function = fn.WRITE_MACROS
        except ValueError:
            extra = struct.pack(">d", value)
            request = fn.WRITE_MACRO_DOUBLE.request(number, extra=extra, path=self.path)
            function = fn.WRITE_MACRO_DOUBLE
        await self._call(function, request)

    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:
        try:
            adr_type = fn.pmc_adr_type(area)
        except ValueError as exc:
            raise OutOfRange(3, "write_pmc", message=str(exc)) from None
        request = fn.WRITE_PMC.request(start, start + len(data) - 1, adr_type, 0, extra=data, path=self.path)
        await self._call(fn.WRITE_PMC, request)

    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None:
        raise NotSupported("write_param", "no public FOCAS/Ethernet wire code for cnc_wrparam is known")

    async def _set_clock(self, when: datetime) -> None:
        """Only the time of day has a published wire form (0x46); the date must already be right."""
        date_request = fn.READ_CLOCK.request(fn.CLOCK_DATE, path=self.path)
        (answer,) = await self._exchange([date_request])
        cnc_date = fn.READ_CLOCK.decode_response(answer, date_request, self.context)
        if isinstance(cnc_date, date) and cnc_date != when.date():
            raise NotSupported("set_clock", f"the CNC date is {cnc_date} but {when.date()} was asked; "
                                            "setting the date has no public wire code")
        request = fn.SET_TIME.request(fn.CLOCK_TIME, extra=fn.set_time_request(when.time()).extra,
                                      path=self.path)
        await self._call(fn.SET_TIME, request)

    # ---- plumbing ---------------------------------------------------------------------------------------
    def _prepare(self, items: Sequence[it.ReadItem]) -> PreparedBatch:
        """The batch's PDUs; built once per tuple of items a caller repeats (a poller's tick), per session.

        Only tuples are kept (a list could change under the cache); the cache pins the tuple, so its
        identity cannot be reused by another object while the entry lives. A batch of a list is built with
        a memo of its own, kept by nobody.
        """
        if type(items) is not tuple:
            return self._build_batch(items, SessionValues())
        prepared = self._prepared.get(id(items))
        if prepared is None or prepared.items is not items or prepared.context is not self.context:
            if len(self._prepared) >= PREPARED_CACHE_SIZE or any(
                    p.context is not self.context for p in self._prepared.values()):
                self._prepared.clear()
                self._memo = SessionValues()
            prepared = self._build_batch(items, self._memo)
            self._prepared[id(items)] = prepared
        return prepared

    def _build_batch(self, items: Sequence[it.ReadItem], memo: SessionValues) -> PreparedBatch:
        # plan_item is pure and a poll repeats the same items every tick: plans (and their request subpackets)
        # come from the process's shared cache (building them was 12% of the CPU at 200 machines).
        plans = [shared_plan_item(item, self.context, self.path) for item in items]
        value_slots = memo.slots_for(plans)
        pdus = []
        for layout in self._layouts(plans):
            slots = intern_ints(tuple(value_slots[index] for index in layout.indices))
            splitter = AnswerSplitter(layout.echoes, memo.pieces_of(slots), memo.answers) if layout.echoes else None
            pdus.append(PreparedPdu(layout, splitter, slots))
        return PreparedBatch(items, self.context, memo, tuple(pdus), slot_getter(intern_ints(tuple(value_slots))))

    def _layouts(self, plans: list[ItemPlan]) -> tuple[PduLayout, ...]:
        """The PDUs for these plans, shared by every session asking the same ones (the key's plans are held by
        the value, so their ids stay theirs while the entry lives)."""
        key = (self.max_subpackets, *map(id, plans))
        found = _LAYOUTS.get(key)
        if found is None:
            found = tuple(_pdu_layout(group) for group in self._groups(plans))
            if len(_LAYOUTS) >= LAYOUTS_LIMIT:
                _LAYOUTS.clear()
            _LAYOUTS[key] = found
        return found

    def _groups(self, plans: list[ItemPlan]) -> list[list[tuple[int, ItemPlan]]]:
        """Items in order, packed into PDUs of at most max_subpackets subpackets."""
        groups: list[list[tuple[int, ItemPlan]]] = [[]]
        used = 0
        for index, plan in enumerate(plans):
            need = len(plan.calls)
            if used and used + need > self.max_subpackets:
                groups.append([])
                used = 0
            groups[-1].append((index, plan))
            used += need
        return groups

    async def _call(self, function: Function, request: RequestSubpacket) -> None:
        (answer,) = await self._exchange([request])
        if answer.rc != 0:
            raise cnc_error(answer.rc, function.name, answer.detail)

    async def _exchange(self, requests: list[RequestSubpacket]) -> list[ResponseSubpacket]:
        """One 0x2101 out, one 0x2102 back; every echo and the count checked."""
        frame = await self._roundtrip(encode_request(requests), PduType.DATA_RESPONSE, "data request")
        answers = decode_response_body(frame.body)
        if len(answers) != len(requests):
            raise ProtocolError(f"{self.describe()}: expected {len(requests)} subpackets in the answer, "
                                f"got {len(answers)}")
        for index, (req, sub) in enumerate(zip(requests, answers, strict=True)):
            if not sub.answers(req):
                raise ProtocolError(f"{self.describe()}: subpacket {index} should echo class {req.cls} path "
                                    f"{req.path} command 0x{req.command:04x}, got class {sub.cls} path "
                                    f"{sub.path} command 0x{sub.command:04x}")
        return answers

    async def _roundtrip(self, data: bytes, expected: PduType, what: str) -> Frame:
        stream = self._stream
        if stream is None:
            raise ConnectionLost(f"{self.describe()}: not connected")
        self._in_flight = True
        stream.send(data)
        self.pdus_sent += 1
        frames = stream.frames
        while not frames:  # stream.next_frame, inline: one coroutine less on every request's await chain
            await stream.arrival()
        frame = frames.pop(0)
        if frame.type != expected:
            raise ProtocolError(f"{self.describe()}: {what}: expected a 0x{int(expected):04x} frame, "
                                f"got type 0x{frame.type:04x} ({len(frame.body)} body bytes)")
        self._in_flight = False
        return frame

    async def _say_goodbye(self, stream: FrameStream) -> None:
        stream.send(encode_close_request())
        while True:
            frame = await stream.next_frame()
            if frame.type == PduType.CLOSE_RESPONSE:
                return


def _pdu_layout(group: list[tuple[int, ItemPlan]]) -> PduLayout:
    requests = [req for _, plan in group for req in plan.requests]
    starts: list[int] = []
    owners: list[int] = []
    for entry, (_, plan) in enumerate(group):
        starts.append(len(owners))
        owners += [entry] * len(plan.calls)
    single = tuple((plan.calls[0][0].decode_payload, plan.calls[0][1], plan.calls[0][0].name)
                   if plan.error is None and len(plan.calls) == 1 and plan.combine is first_value else None
                   for _, plan in group)
    return PduLayout(encode_request(requests) if requests else b"", tuple(plan for _, plan in group),
                     intern_ints(tuple(index for index, _ in group)), intern_ints(tuple(starts)), single,
                     intern_ints(tuple(owners)), tuple((req.cls, req.path, req.command) for req in requests))


def _answered(answers: Sequence[Answer | None], splitter: AnswerSplitter | None, body: bytes, start: int,
              count: int) -> list[Answer]:
    """The answers of subpackets start..start+count-1 (an item of several calls), parsing those not parsed yet."""
    got = []
    for index in range(start, start + count):
        answer = answers[index] if answers else None
        got.append(cast(AnswerSplitter, splitter).answer(body, index) if answer is None else answer)
    return got
