"""One CNC session, whatever the transport: the API the daemon, the CLI and the command executor use.

The write rules that must hold on every transport live here once: PMC ranges over 32 bytes are split
into 32-byte calls in order; PMC bit writes and bit-parameter writes are read-modify-write under a
lock per byte, so concurrent bit writes to one byte never lose each other's bit. Transports implement
only the small abstract hooks (connect/close, one batch of reads, one raw write of each kind).
"""

from __future__ import annotations

import abc
import asyncio
import logging
from collections.abc import Coroutine, Sequence
from datetime import datetime
from typing import Any, ClassVar, TypeVar

from tenacity import (
    AsyncRetrying,
    RetryCallState,
    retry_if_exception_type,
    stop_after_delay,
    wait_random_exponential,
)

from edge.focas import items as it
from edge.focas.deadline import Deadline, DeadlineWheel, wheel_for
from edge.focas.errors import (
    ConnectionLost,
    FocasError,
    FocasTimeout,
    NotSupported,
    OutOfRange,
    ProtocolError,
)
from edge.focas.model import (
    AlarmHistoryEntry,
    Capabilities,
    ParamRecord,
    ParamType,
    PmcType,
    StatInfo,
    SysInfo,
)
from edge.focas.outage import ConnectOutage

log = logging.getLogger(__name__)

PMC_WRITE_CHUNK = 32
T = TypeVar("T")
ItemResult = Any  # the decoded value, or the FocasError that item raised


class CncSession(abc.ABC):
    """Async context manager over one CNC; many tasks may share it (requests are serialised)."""

    transport: ClassVar[str] = "abstract"

    def __init__(
        self,
        *,
        timeout: float = 5.0,
        connect_timeout: float = 5.0,
        backoff_initial: float = 0.5,
        backoff_max: float = 30.0,
    ) -> None:
        self.timeout = timeout
        self.connect_timeout = connect_timeout
        self.backoff_initial = backoff_initial
        self.backoff_max = backoff_max
        self.sysinfo: SysInfo | None = None
        self._io_lock = asyncio.Lock()
        self._byte_locks: dict[tuple[str, int], asyncio.Lock] = {}
        self._param_locks: dict[tuple[int, int], asyncio.Lock] = {}
        self._connected = False
        self._wheel: DeadlineWheel | None = None  # the request deadlines of the loop this session runs on

    # ---- transport hooks -------------------------------------------------------------------------
    @abc.abstractmethod
    async def _open(self) -> SysInfo:
        """Connect, handshake and read sysinfo; return it."""

    @abc.abstractmethod
    async def _close(self) -> None:
        """Send the close PDU where the transport has one, then close the socket; never raise."""

    @abc.abstractmethod
    async def _batch(self, items: Sequence[it.ReadItem]) -> list[ItemResult]:
        """Read every item in as few round trips as the transport allows (native: one PDU)."""

    @abc.abstractmethod
    async def _write_macro(self, number: int, value: float) -> None: ...

    @abc.abstractmethod
    async def _write_pmc_bytes(self, area: str, start: int, data: bytes) -> None:
        """One PMC byte-range write of at most 32 bytes."""

    @abc.abstractmethod
    async def _write_param(self, number: int, axis: int, ptype: int, value: int | float) -> None: ...

    async def _set_clock(self, when: datetime) -> None:
        raise NotSupported("set_clock", f"the {self.transport} transport has no clock write")

    @property
    @abc.abstractmethod
    def capabilities(self) -> Capabilities: ...

    # ---- lifecycle ---------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected

    async def connect(self) -> SysInfo:
        try:
            async with asyncio.timeout(self.connect_timeout):
                self.sysinfo = await self._open()
        except TimeoutError as exc:
            await self._close()
            raise FocasTimeout(f"connect: no answer within {self.connect_timeout}s") from exc
        except FocasError:
            await self._close()
            raise
        except OSError as exc:
            await self._close()
            raise ConnectionLost(f"connect: {exc}") from exc
        self._connected = True
        return self.sysinfo

    async def connect_with_retry(self, deadline: float | None = None) -> SysInfo:
        """Connect, retrying with capped exponential backoff and jitter; each retry logged once."""

        outage = ConnectOutage(f"peer={self.describe()}", log)

        def _log(state: RetryCallState) -> None:
            exc = state.outcome.exception() if state.outcome else None
            outage.failed(exc, state.next_action.sleep if state.next_action else 0.0)

        retrying = AsyncRetrying(
            retry=retry_if_exception_type(FocasError),
            wait=wait_random_exponential(multiplier=self.backoff_initial, max=self.backoff_max),
            stop=stop_after_delay(deadline) if deadline is not None else (lambda _state: False),
            before_sleep=_log,
            reraise=True,
        )
        async for attempt in retrying:
            with attempt:
                sysinfo = await self.connect()
                outage.connected()
                return sysinfo
        raise AssertionError("unreachable")  # pragma: no cover

    async def close(self) -> None:
        self._connected = False
        await self._close()

    async def reset(self) -> None:
        """Drop the session after a timeout or protocol error so the next use reconnects cleanly."""
        self._connected = False
        await self._close()

    async def __aenter__(self) -> CncSession:
        await self.connect()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    def describe(self) -> str:
        return self.transport

    # ---- reads -----------------------------------------------------------------------------------
    def batch(self, items: Sequence[it.ReadItem]) -> Coroutine[Any, Any, list[ItemResult]]:
        """One result per item, in order: its value, or the FocasError that item alone raised.

        Not a coroutine of its own: the request is awaited through one level less (every level of the await
        chain is re-entered when the answer wakes the task, ten times a second per machine)."""
        return self._locked(self._batch(items))

    async def read(self, item: it.ReadItem) -> Any:
        """One item; its error is raised."""
        (result,) = await self.batch([item])
        if isinstance(result, FocasError):
            raise result
        return result

    async def read_sysinfo(self) -> SysInfo:
        return await self.read(it.ReadSysInfo())

    async def read_status(self) -> StatInfo:
        return await self.read(it.ReadStatus())

    async def read_macros(self, first: int, last: int | None = None) -> list[float | None]:
        return await self.read(it.ReadMacros(first, first if last is None else last))

    async def read_pmc(self, area: str, start: int, end: int,
                       data_type: PmcType = PmcType.BYTE) -> list[int | float]:
        return await self.read(it.ReadPmc(area, start, end, data_type))

    async def read_params(self, first: int, last: int | None = None, axis: int = 0) -> list[ParamRecord]:
        return await self.read(it.ReadParams(first, first if last is None else last, axis))

    async def read_diag(self, first: int, last: int | None = None, axis: int = 0) -> list[ParamRecord]:
        return await self.read(it.ReadDiag(first, first if last is None else last, axis))

    async def read_clock(self) -> datetime:
        return await self.read(it.ReadClock())

    async def read_alarm_history(self, depth: int = 100) -> list[AlarmHistoryEntry]:
        return await self.read(it.ReadAlarmHistory(depth))

    # ---- writes ----------------------------------------------------------------------------------
    async def write_macro(self, number: int, value: float) -> None:
        await self._locked_write(self._write_macro(number, value))

    async def write_pmc(self, area: str, start: int, data: bytes) -> None:
        """Write a byte range; over 32 bytes it becomes 32-byte calls, in order."""
        for offset in range(0, len(data), PMC_WRITE_CHUNK):
            chunk = data[offset : offset + PMC_WRITE_CHUNK]
            await self._locked_write(self._write_pmc_bytes(area, start + offset, chunk))

    async def write_pmc_bit(self, area: str, address: int, bit: int, value: bool) -> int:
        """Read the byte, set or clear one bit, write it back; returns the byte written."""
        if not 0 <= bit <= 7:
            raise OutOfRange(3, "write_pmc_bit", message=f"bit {bit} is not 0..7")
        lock = self._byte_locks.setdefault((area, address), asyncio.Lock())
        async with lock:
            (current,) = await self.read_pmc(area, address, address, PmcType.BYTE)
            new = (int(current) | (1 << bit)) if value else (int(current) & ~(1 << bit) & 0xFF)
            await self.write_pmc(area, address, bytes([new]))
            return new

    async def write_param(self, number: int, value: int | float, axis: int = 0) -> ParamRecord:
        """Write a whole parameter; its type comes from reading it first. Returns the record before."""
        lock = self._param_locks.setdefault((number, axis), asyncio.Lock())
        async with lock:
            before = await self._read_param_record(number, axis)
            await self._locked_write(self._write_param(number, axis, before.type, value))
            return before

    async def write_param_bit(self, number: int, bit: int, value: bool, axis: int = 0) -> ParamRecord:
        """Bit-addressed parameter (`param:1815/0.3`): read-modify-write of the parent value."""
        if not 0 <= bit <= 7:
            raise OutOfRange(3, "write_param_bit", message=f"bit {bit} is not 0..7")
        lock = self._param_locks.setdefault((number, axis), asyncio.Lock())
        async with lock:
            before = await self._read_param_record(number, axis)
            current = int(before.value or 0)
            new = (current | (1 << bit)) if value else (current & ~(1 << bit))
            await self._locked_write(self._write_param(number, axis, before.type, new))
            return before

    async def set_clock(self, when: datetime) -> None:
        await self._locked_write(self._set_clock(when))

    async def _read_param_record(self, number: int, axis: int) -> ParamRecord:
        records = await self.read_params(number, number, axis)
        if not records:
            raise OutOfRange(3, "read_param", message=f"parameter {number} not answered")
        record = records[0]
        if record.type not in tuple(ParamType):
            raise OutOfRange(4, "read_param", message=f"parameter {number} has unknown type {record.type}")
        return record

    async def _locked_write(self, operation: Any) -> None:
        await self._locked(operation)

    async def _locked(self, operation: Any) -> Any:
        """Run one request (`operation`, a coroutine) alone on the session, under the request timeout; on
        timeout or protocol trouble, reset the session (never wedge).

        The timeout is a deadline on the loop's shared wheel (edge.focas.deadline), not an
        asyncio.timeout: a poller runs this ten times a second per machine. Like asyncio.timeout (and
        unlike wait_for on Python 3.11), a cancellation from outside is never mistaken for a timeout and
        never swallowed, so a poller cannot survive its shutdown.
        """
        if not self._connected:
            operation.close()
            raise ConnectionLost(f"{self.describe()}: not connected")
        lock = self._io_lock  # `async with`, without its two extra coroutines (a poller's tick comes this way)
        await lock.acquire()
        try:
            task, wheel, deadline, cancelling = self._arm()
            try:
                try:
                    return await operation
                finally:
                    wheel.disarm(deadline)
            except (asyncio.CancelledError, ConnectionLost, OSError, ProtocolError) as exc:
                instead = await self._failed(exc, task, deadline, cancelling)
                if instead is None:
                    raise
                raise instead from exc
        finally:
            lock.release()

    def _arm(self) -> tuple[asyncio.Task[Any], DeadlineWheel, Deadline, int]:
        """The request's deadline, armed on the loop's wheel for the current task."""
        task = asyncio.current_task()
        if task is None:  # pragma: no cover - always called from a task
            raise RuntimeError("CncSession requests must run in an asyncio task")
        wheel = self._wheel
        if wheel is None or not wheel.serves(task.get_loop()):
            wheel = self._wheel = wheel_for(task.get_loop())
        deadline = Deadline()
        cancelling = task.cancelling()
        wheel.arm(deadline, task, self.timeout)
        return task, wheel, deadline, cancelling

    async def _failed(self, exc: BaseException, task: asyncio.Task[Any], deadline: Deadline,
                      cancelling: int) -> BaseException | None:
        """A request ended in `exc`: reset the session where it is broken; the error to raise instead (None:
        `exc` itself). A cancellation from outside (shutdown) is not a timeout and resets nothing."""
        if isinstance(exc, asyncio.CancelledError):
            if not deadline.expired or task.uncancel() > cancelling:
                return None
            await self.reset()
            return FocasTimeout(f"{self.describe()}: no complete answer within {self.timeout}s")
        await self.reset()
        if isinstance(exc, OSError) and not isinstance(exc, ConnectionLost):
            return ConnectionLost(f"{self.describe()}: {exc}")
        return None
