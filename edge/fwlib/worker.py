"""One CNC behind the FOCAS library: its own thread, its own handle, a timeout on every call.

Library calls block (a CNC that stops answering can hold a call for as long as the library likes), so
they never run on the event loop: each CNC has one thread, and the loop awaits its answer with a timeout.
A call that overruns marks that CNC unavailable and abandons its thread (a blocked C call cannot be
interrupted; the thread frees its handle and ends if the call ever returns); a fresh thread and a fresh
handle are opened with backoff. Other CNCs have their own threads and never wait for this one.

A request whose call overran rests: for `hung_rest_s` (doubling while it keeps overrunning, at most
HUNG_REST_MAX_S) the same request (command and payload) answers EW_SOCKET at once without calling the
library, so one function that hangs on every call (issue 24: cnc_rdalmhistry3) costs the other reads of its
CNC one call timeout and one reopen per rest, not per poll, and abandons one blocked thread per rest. The
first request after the rest is tried for real.

While a CNC is unavailable every request answers EW_SOCKET (-16), which the client reports per item. A
request whose translation fails in a way no translation expects (a bug, not a CNC answer) is logged with its
traceback and answers EW_UNEXP (-6); the handle and the connection stay, so the next request is served.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from tenacity import AsyncRetrying, RetryCallState, retry_if_exception_type, wait_random_exponential

from edge.focas.errors import EW_SOCKET, EW_UNEXP
from edge.focas.model import ParamType
from edge.focas.outage import ConnectOutage
from edge.focas.packed.endpoint import error_answer
from edge.fwlib.calls import LibraryCnc, answer
from edge.fwlib.library import FocasLibrary

log = logging.getLogger(__name__)

UNAVAILABLE = EW_SOCKET  # the answer for every request while the CNC is unavailable
HUNG_REST_MAX_S = 600.0  # the longest a command that keeps hanging rests between two real calls


class ConnectFailed(Exception):
    """cnc_allclibhndl3 failed or overran; retried with backoff."""


@dataclass(frozen=True)
class CncTarget:
    """Where one CNC is and what the host must know about it."""

    name: str
    host: str
    port: int = 8193
    param_types: dict[int, ParamType] = field(default_factory=dict)
    diag_types: dict[int, ParamType] = field(default_factory=dict)
    input_decimals: int = 3  # the least input increment's decimals: cnc_rdzofs answers integers in it


@dataclass(frozen=True)
class WorkerTimeouts:
    call_s: float = 3.0
    connect_s: float = 10.0
    backoff_initial_s: float = 0.5
    backoff_max_s: float = 30.0
    hung_rest_s: float = 60.0  # a command whose call overran answers EW_SOCKET without a call this long


def _settle(future: asyncio.Future[Any], result: Any, error: BaseException | None) -> None:
    if future.done():  # the waiter gave up (timeout) or was cancelled
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


class CallThread:
    """A daemon thread running submitted calls in order; a blocked call cannot stop the process exiting."""

    def __init__(self, name: str) -> None:
        self._jobs: queue.SimpleQueue[tuple[Callable[[], Any], Any, Any] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, call: Callable[[], Any]) -> asyncio.Future[Any]:
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Any] = loop.create_future()
        self._jobs.put((call, loop, future))
        return future

    def retire(self, last: Callable[[], Any] | None = None) -> None:
        """Run `last` (e.g. free the handle) after whatever is running, then end the thread."""
        if last is not None:
            self._jobs.put((last, None, None))
        self._jobs.put(None)

    def join(self, timeout: float) -> bool:
        """Wait (blocking) for the thread to end; False if a call is still blocked after `timeout`."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            call, loop, future = job
            result: Any = None
            error: BaseException | None = None
            try:
                result = call()
            except Exception as exc:
                error = exc
            if loop is not None:
                with contextlib.suppress(RuntimeError):  # the loop closed while the call was blocked
                    loop.call_soon_threadsafe(_settle, future, result, error)


class HandleWorker:
    """Serves packed requests for one CNC through the library, on that CNC's own thread and handle."""

    def __init__(self, library: FocasLibrary, target: CncTarget, timeouts: WorkerTimeouts) -> None:
        self.library = library
        self.target = target
        self.timeouts = timeouts
        self._thread: CallThread | None = None
        self._cnc: LibraryCnc | None = None
        self._lock = asyncio.Lock()
        self._connector: asyncio.Task[None] | None = None
        self.connects = 0
        self._outage = ConnectOutage(f"machine={target.name} address={target.host}:{target.port}", log)
        # (command, payload) of a request whose call overran -> (monotonic end of its rest, rest in s)
        self._resting: dict[tuple[int, bytes], tuple[float, float]] = {}

    @property
    def available(self) -> bool:
        return self._cnc is not None

    def start(self) -> None:
        """Open the handle in the background (with backoff); requests answer EW_SOCKET until it is open."""
        if self._connector is None or self._connector.done():
            self._connector = asyncio.create_task(self._connect(), name=f"fwlib-connect-{self.target.name}")

    async def wait_available(self) -> None:
        while not self.available:
            if self._connector is not None:
                await asyncio.wait({self._connector})
            if not self.available:
                self.start()

    async def close(self, join_timeout_s: float = 5.0) -> None:
        """Stop reconnecting and free the handle on its thread (waiting for that, unless a call is blocked)."""
        if self._connector is not None:
            self._connector.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._connector
        thread = self._drop("host stopping")
        if thread is not None and not await asyncio.to_thread(thread.join, join_timeout_s):
            log.warning("a FOCAS library call is still blocked at shutdown machine=%s", self.target.name)

    async def respond(self, command: int, payload: bytes) -> bytes:
        async with self._lock:  # one call at a time per handle, each with its own timeout
            cnc, thread = self._cnc, self._thread
            request = (command, payload)
            if cnc is None or thread is None or self._rests(request):
                return error_answer(command, UNAVAILABLE)
            try:
                reply: bytes = await asyncio.wait_for(thread.submit(lambda: answer(cnc, command, payload)),
                                                      self.timeouts.call_s)
            except TimeoutError:
                rest_s = self._rest(request)
                log.error("FOCAS library call overran its timeout; CNC marked unavailable, the request answers "
                          "EW_SOCKET without a call for rest_s=%g machine=%s command=0x%04X timeout_s=%s",
                          rest_s, self.target.name, command, self.timeouts.call_s)
                self._drop("call timed out")
                self.start()
                return error_answer(command, UNAVAILABLE)
            except Exception:
                log.exception("FOCAS library host could not translate a request; answering EW_UNEXP "
                              "machine=%s command=0x%04X", self.target.name, command)
                reply = error_answer(command, EW_UNEXP)
            if self._resting:
                self._resting.pop(request, None)  # it answered in time: its next overrun rests hung_rest_s again
            if cnc.lost_code:
                log.warning("FOCAS library lost the CNC handle; reconnecting machine=%s ew=%d",
                            self.target.name, cnc.lost_code)
                self._drop(f"EW {cnc.lost_code}")
                self.start()
            return reply

    def _rests(self, request: tuple[int, bytes]) -> bool:
        """Whether `request` is resting after an overrun (answered EW_SOCKET without a library call)."""
        resting = self._resting.get(request) if self._resting else None
        return resting is not None and time.monotonic() < resting[0]

    def _rest(self, request: tuple[int, bytes]) -> float:
        """Start `request`'s rest after an overrun: hung_rest_s, doubled for each overrun in a row."""
        now = time.monotonic()
        for other, (until, _) in list(self._resting.items()):  # forget rests long over (requests not seen since)
            if now - until > HUNG_REST_MAX_S:
                del self._resting[other]
        previous = self._resting.get(request)
        rest_s = self.timeouts.hung_rest_s if previous is None else min(2 * previous[1], HUNG_REST_MAX_S)
        self._resting[request] = (now + rest_s, rest_s)
        return rest_s

    def _drop(self, reason: str) -> CallThread | None:
        """Forget the handle and its thread; the thread frees the handle once its current call returns."""
        cnc, thread = self._cnc, self._thread
        self._cnc = self._thread = None
        if thread is not None:
            library = self.library
            thread.retire((lambda: library.call("cnc_freelibhndl", cnc.handle)) if cnc is not None else None)
        if cnc is not None:
            log.info("CNC handle released machine=%s reason=%s", self.target.name, reason)
        return thread

    async def _connect(self) -> None:
        def before_sleep(state: RetryCallState) -> None:
            error = state.outcome.exception() if state.outcome else None
            self._outage.failed(f"FOCAS library could not open the CNC: {error}",
                                state.next_action.sleep if state.next_action else None)

        retrying = AsyncRetrying(
            retry=retry_if_exception_type(ConnectFailed),
            wait=wait_random_exponential(multiplier=self.timeouts.backoff_initial_s,
                                         max=self.timeouts.backoff_max_s),
            before_sleep=before_sleep,
        )
        async for attempt in retrying:
            with attempt:
                await self._connect_once()
        self._outage.connected()

    async def _connect_once(self) -> None:
        thread = CallThread(f"fwlib-{self.target.name}")
        target, library = self.target, self.library
        timeout_s = max(1, round(self.timeouts.connect_s))

        def open_handle() -> int:
            handle = ctypes.c_ushort()
            code = library.call("cnc_allclibhndl3", target.host.encode(), target.port, timeout_s,
                                ctypes.byref(handle))
            if code != 0:
                raise ConnectFailed(f"cnc_allclibhndl3 answered EW {code}")
            return handle.value

        try:
            handle = await asyncio.wait_for(thread.submit(open_handle), self.timeouts.connect_s + 1.0)
        except TimeoutError:
            thread.retire()
            raise ConnectFailed(f"cnc_allclibhndl3 overran {self.timeouts.connect_s + 1.0} s") from None
        except ConnectFailed:
            thread.retire()
            raise
        self._thread = thread
        self._cnc = LibraryCnc(library, handle, dict(target.param_types), dict(target.diag_types),
                               input_decimals=target.input_decimals)
        self.connects += 1
        log.info("CNC handle open machine=%s address=%s:%d handle=%d", target.name, target.host, target.port,
                 handle)
