"""The OPC UA server as one more output of the daemon: the same births, data, events and offlines the
MQTT publisher gets, handed to the server without ever waiting on it.

The collector calls the `device_*` methods on the daemon's loop; they append to a mailbox and return
(no await on the server). The server drains the mailbox on its event loop: by default the daemon's own,
or (`threaded`) a loop in a thread of its own. On the daemon's own loop a data batch (a thousand a
second at 100 machines x 10 Hz) is applied in the call instead, when nothing is queued before it: setting
the values and telling the gateway's monitored items is synchronous work the drain would do a moment
later on the same loop, so the mailbox entry and the drain task's wake-up per batch are saved.

Measured at 100 machines x 10 Hz with a client subscribed to everything (docs/opcua.md), the daemon's
loop serves better: in a thread the server's steady work
takes the interpreter lock in 5 ms slices and the poll loop, which wakes a thousand times a second,
waits for it (poll overruns, MQTT p99 up 2-3x); only a single huge request (10,000 monitored items at
once) holds the daemon's loop longer than the thread would.

A client's write travels the other way: from the server's loop to the daemon's `MetricWriter` (the
command layer), and the server waits for its outcome up to `write_timeout_s` without cancelling it: a
write that has started is carried out and audited even when the client has gone.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import threading
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from edge.opcua.address_space import deliver
from edge.opcua.server import GatewayServer, MetricWrite, MetricWriter
from edge.opcua.settings import OpcUaSettings
from edge.opcua.writes import WriteOutcome
from edge.samples import MetricSpec, Sample

log = logging.getLogger(__name__)

MAILBOX_LIMIT = 20_000  # data batches waiting for the server; beyond it a batch is dropped and counted
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0

# (device id, writable metric names) -> those the write policy covers: the nodes' AccessLevel
Writable = Callable[[str, Sequence[str]], frozenset[str]]


class OpcUaOutput:
    """A DeviceSink feeding a GatewayServer that runs in its own thread or on the caller's loop."""

    def __init__(self, settings: OpcUaSettings, writer: MetricWriter | None = None,
                 writable: Writable | None = None) -> None:
        self.settings = settings
        self.writable = writable
        self._writer = writer
        self.server = GatewayServer(settings, self._write if writer is not None else None)
        self._mailbox: deque[tuple[Any, ...]] = deque()
        self._wake_pending = False
        self._inline = False  # data batches applied in device_data: the server runs on the daemon's loop
        self._show_now: Callable[[str, Sequence[Sample]], list[Any]] = self.server.show_data
        self._draining = False
        self._wake: asyncio.Event | None = None
        self._server_loop: asyncio.AbstractEventLoop | None = None
        self._daemon_loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._drain: asyncio.Task[None] | None = None
        self._stopped: concurrent.futures.Future[None] | None = None
        self._finish: asyncio.Event | None = None
        self._writes: set[asyncio.Future[WriteOutcome]] = set()
        self.dropped = 0
        self.failures = 0

    # ---- lifecycle ---------------------------------------------------------------------------------
    async def start(self) -> None:
        """Start the server; raises what stopped it from listening (port taken, bad certificate)."""
        self._daemon_loop = asyncio.get_running_loop()
        if not self.settings.threaded:
            await self._serve_start()
            return
        started: concurrent.futures.Future[None] = concurrent.futures.Future()
        self._stopped = concurrent.futures.Future()
        self._thread = threading.Thread(target=self._thread_main, args=(started,), name="opcua", daemon=True)
        self._thread.start()
        try:
            await asyncio.wait_for(asyncio.wrap_future(started), START_TIMEOUT_S)
        except BaseException:
            await self.stop()
            raise

    async def stop(self) -> None:
        if self._thread is None:
            await self._serve_stop()
            return
        loop, thread = self._server_loop, self._thread
        self._thread = None
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop already ended
                loop.call_soon_threadsafe(self._request_stop)
        await asyncio.to_thread(thread.join, STOP_TIMEOUT_S)
        if thread.is_alive():
            log.error("OPC UA server thread did not stop within %.0fs", STOP_TIMEOUT_S)

    def _thread_main(self, started: concurrent.futures.Future[None]) -> None:
        loop = asyncio.new_event_loop()
        self._server_loop = loop
        try:
            loop.run_until_complete(self._thread_serve(started))
        finally:
            # what asyncua leaves behind (sessions of clients that vanished, their subscription loops)
            left = asyncio.all_tasks(loop)
            for task in left:
                task.cancel()
            with contextlib.suppress(Exception):
                loop.run_until_complete(asyncio.gather(*left, return_exceptions=True))
                loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

    async def _thread_serve(self, started: concurrent.futures.Future[None]) -> None:
        finish = self._finish = asyncio.Event()
        try:
            await self._serve_start()
        except BaseException as exc:
            started.set_exception(exc)
            return
        started.set_result(None)
        try:
            await finish.wait()
        finally:
            await self._serve_stop()

    def _request_stop(self) -> None:
        if self._finish is not None:
            self._finish.set()

    async def _serve_start(self) -> None:
        self._server_loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        await self.server.start()
        self._drain = asyncio.create_task(self._drain_loop(), name="opcua-drain")
        self._show_now = self.server.show_data  # (the address space's own method, once the server has started)
        self._inline = self._thread is None
        if self._mailbox:  # posted before the server was up
            self._wake_pending = True
            self._wake.set()

    async def _serve_stop(self) -> None:
        self._inline = False
        drain, self._drain = self._drain, None
        if drain is not None:
            drain.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await drain
        await self.server.stop()

    # ---- the collector's side (daemon loop): never waits on the server ------------------------------
    async def device_online(self, device_id: str, specs: Sequence[MetricSpec], samples: Sequence[Sample]) -> None:
        names = [spec.name for spec in specs if spec.writable]
        writable = frozenset(names) if self.writable is None else self.writable(device_id, names)
        self._post(("online", device_id, tuple(specs), tuple(samples), writable))

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None:
        if self._inline and not self._mailbox and not self._draining:
            # Applied in the call (the values set, the gateway's monitored items told, synchronously, as the
            # drain would a moment later) without a mailbox entry and a drain wake-up per batch, and with no
            # Python call between here and the address space (every poll tick with a change comes this
            # way, a client or not). Items on asyncua's path are awaited by the drain, in order.
            try:
                slow = self._show_now(device_id, samples)
            except Exception:
                self.failures += 1
                log.exception("OPC UA server could not apply kind=data machine=%s", device_id)
                return
            if slow:
                self._post(("deliver", device_id, slow))
            return
        if len(self._mailbox) >= MAILBOX_LIMIT:
            self.dropped += len(samples)
            if self.dropped == len(samples):
                log.warning("OPC UA server falls behind: value changes dropped (counted in dropped)")
            return
        self._post(("data", device_id, samples))

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None:
        self._post(("events", device_id, events))

    async def device_offline(self, device_id: str) -> None:
        self._post(("offline", device_id))

    def _post(self, item: tuple[Any, ...]) -> None:
        self._mailbox.append(item)
        if self._wake_pending:
            return
        loop, wake = self._server_loop, self._wake
        if loop is None or wake is None:
            return  # not started: the first drain takes it
        self._wake_pending = True
        if self._thread is None:
            wake.set()
        else:
            with contextlib.suppress(RuntimeError):  # the server loop has ended
                loop.call_soon_threadsafe(wake.set)

    # ---- the server's side ----------------------------------------------------------------------------
    async def _drain_loop(self) -> None:
        assert self._wake is not None
        wake, mailbox, server = self._wake, self._mailbox, self.server
        while True:
            await wake.wait()
            wake.clear()
            self._wake_pending = False  # before draining: a post after this point wakes us again
            self._draining = True  # an item being applied is out of the mailbox: later data must queue
            while mailbox:
                item = mailbox.popleft()
                try:
                    await self._apply(server, item)
                except Exception:
                    self.failures += 1
                    log.exception("OPC UA server could not apply kind=%s machine=%s", item[0], item[1])
            self._draining = False

    @staticmethod
    async def _apply(server: GatewayServer, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "data":
            await server.machine_data(item[1], item[2])
        elif kind == "events":
            await server.machine_events(item[1], item[2])
        elif kind == "online":
            await server.machine_online(item[1], item[2], item[3], item[4])
        elif kind == "offline":
            await server.machine_offline(item[1])
        elif kind == "deliver":
            await deliver(item[2])

    async def _write(self, request: MetricWrite) -> WriteOutcome:
        """Run the write on the daemon's loop; wait up to write_timeout_s, never cancel it."""
        assert self._writer is not None and self._daemon_loop is not None
        writer = self._writer
        if self._thread is None:
            future: asyncio.Future[WriteOutcome] = asyncio.ensure_future(writer(request))
            self._writes.add(future)  # owned here until done, even when the client's request is cancelled
            future.add_done_callback(self._writes.discard)
        else:
            future = asyncio.wrap_future(asyncio.run_coroutine_threadsafe(writer(request), self._daemon_loop))
        done, _ = await asyncio.wait({future}, timeout=self.settings.write_timeout_s)
        if not done:
            return WriteOutcome(False, "timeout", f"no outcome within {self.settings.write_timeout_s:g} s")
        return future.result()

    @property
    def pending(self) -> int:
        """Mailbox entries the server has not applied yet."""
        return len(self._mailbox)
