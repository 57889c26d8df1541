"""One write queue per machine: requests run one at a time, in arrival order, on the machine's session.

The session is shared with the poller; its io lock interleaves our requests with poll ticks, so writes
and polling are serialised on the one TCP connection. For each write:

1. wait until the poller has the CNC session up (up to `reconnect_deadline_s` after the request arrived);
2. read the target (the old value for the audit line; a parameter's type to check the value against);
3. write through the session call for the target's kind;
4. read the target back (with the plan's reads it touches, whose values go to DDATA / JSON state).

A write that got no answer (timeout, connection lost mid-request) is NEVER sent again: once the session
is back, the target is re-read; the reply says whether the value is there (ok, with a note), is not
(`not_applied`), or could not be learned (`timeout`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from edge.collect import metric_values
from edge.command import target_io
from edge.command.dcmd import reads_touching
from edge.command.errors import CommandRefused, ErrorCode, code_for, refused_by_cnc
from edge.command.requests import WriteOp
from edge.command.results import WriteResult
from edge.focas.errors import ConnectionLost, FocasError, FocasTimeout, ProtocolError
from edge.focas.targets import MacroTarget, ParamTarget
from edge.samples import Sample

if TYPE_CHECKING:
    from edge.collect import MachinePoller

log = logging.getLogger(__name__)

READY_POLL_S = 0.05  # session up but its socket gone: the poller notices at its next tick
MAX_QUEUED_REQUESTS = 32
UNCERTAIN = (FocasTimeout, ConnectionLost, ProtocolError)  # the request may have reached the CNC


@dataclass
class Job:
    ops: Sequence[WriteOp]
    received: float  # time.monotonic() at arrival: the reconnect deadline counts from here
    done: asyncio.Future[list[WriteResult]] = field(default_factory=lambda: asyncio.get_running_loop().create_future())


class MachineWriteQueue:
    """Runs one machine's write requests in order; `pollers` is looked up at use (it changes on reload)."""

    def __init__(self, machine_id: str, pollers: Mapping[str, MachinePoller],
                 deadline_s: Callable[[], float]) -> None:
        self.machine_id = machine_id
        self._pollers = pollers
        self._deadline_s = deadline_s
        self._queue: asyncio.Queue[Job] = asyncio.Queue(MAX_QUEUED_REQUESTS)
        self._worker: asyncio.Task[None] | None = None

    def submit(self, ops: Sequence[WriteOp]) -> asyncio.Future[list[WriteResult]]:
        """Queue a request; its future gives one result per op (skipped after the first failure)."""
        job = Job(ops, time.monotonic())
        try:
            self._queue.put_nowait(job)
        except asyncio.QueueFull:
            raise CommandRefused(ErrorCode.QUEUE_FULL, f"{MAX_QUEUED_REQUESTS} requests already wait for "
                                 f"machine {self.machine_id}") from None
        if self._worker is None or self._worker.done():
            self._worker = asyncio.get_running_loop().create_task(self._work(), name=f"writes-{self.machine_id}")
        return job.done

    async def close(self) -> None:
        """Stop the worker (a write in flight is cancelled); waiting requests fail with shutting_down."""
        if self._worker is not None:
            self._worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._worker
        while not self._queue.empty():
            job = self._queue.get_nowait()
            refusal = CommandRefused(ErrorCode.SHUTTING_DOWN, "the daemon is stopping; nothing was written")
            if not job.done.done():
                job.done.set_result([WriteResult.refused(op, refusal) for op in job.ops])

    async def _work(self) -> None:
        while True:
            job = await self._queue.get()
            try:
                results = await self.run(job.ops, job.received)
            except asyncio.CancelledError:
                if not job.done.done():
                    refusal = CommandRefused(ErrorCode.SHUTTING_DOWN, "the daemon stopped during the write")
                    job.done.set_result([WriteResult.refused(op, refusal) for op in job.ops])
                raise
            except Exception as exc:  # a bug must not kill the queue; the caller gets an answer
                log.exception("write request failed machine=%s", self.machine_id)
                refusal = CommandRefused(ErrorCode.CNC_ERROR, f"internal error: {exc!r}")
                results = [WriteResult.refused(op, refusal) for op in job.ops]
            if not job.done.done():
                job.done.set_result(results)

    async def run(self, ops: Sequence[WriteOp], received: float) -> list[WriteResult]:
        """Apply `ops` in order, stopping at the first failure."""
        results: list[WriteResult] = []
        for index, op in enumerate(ops):
            result = await self.execute(op, received)
            results.append(result)
            if not result.ok:
                results.extend(WriteResult.skipped(rest, index) for rest in ops[index + 1 :])
                break
        return results

    # ---- one write -----------------------------------------------------------------------------------
    async def execute(self, op: WriteOp, received: float) -> WriteResult:
        old: object = None
        try:
            poller, old = await self._read_before(op, received + self._deadline_s())
            try:
                await target_io.apply(poller.session, op)
            except UNCERTAIN as exc:
                return await self._verify(op, old, exc)
            except FocasError as exc:
                return WriteResult.refused(op, refused_by_cnc(exc), old)
            current, cnc_time = await self._read_back(poller, op)
        except CommandRefused as refusal:
            return WriteResult.refused(op, refusal, old)
        if isinstance(current, FocasError):
            return WriteResult(op, True, old=old, cnc_time_ms=cnc_time,
                               note=f"written; the read-back failed: {current}")
        return WriteResult(op, True, old=old, read_back=current, cnc_time_ms=cnc_time)

    async def _read_before(self, op: WriteOp, deadline: float) -> tuple[MachinePoller, object]:
        """The ready poller and the target's value now; a lost session is waited for (nothing sent yet)."""
        while True:
            poller = await self._wait_ready(deadline)
            _check_capability(poller, op)
            try:
                result = await poller.session.read(target_io.read_item(op.target))
            except UNCERTAIN as exc:
                log.info("read before write failed, waiting for the session machine=%s error=%s",
                         self.machine_id, exc)
                continue
            except FocasError as exc:
                raise refused_by_cnc(exc) from None
            if isinstance(op.target, ParamTarget):
                target_io.check_param(op, target_io.param_record(op.target, result))
            return poller, target_io.current_value(op.target, result)

    async def _verify(self, op: WriteOp, old: object, error: FocasError) -> WriteResult:
        """The write got no answer: re-read (never re-send) once the session is back, and say what is there."""
        log.warning("write unanswered, re-reading machine=%s target=%s error=%s", self.machine_id, op.text, error)
        what = f"the CNC did not answer the write ({code_for(error)}: {error})"
        unknown = "unknown whether it was applied (it was not sent again)"
        try:
            poller = await self._wait_ready(time.monotonic() + self._deadline_s())
        except CommandRefused:
            message = (f"{what}; the target could not be re-read: no CNC session within the reconnect deadline "
                       f"({self._deadline_s():g} s); {unknown}")
            return WriteResult(op, False, ErrorCode.TIMEOUT, message, old=old)
        try:
            current, cnc_time = await self._read_back(poller, op)
        except FocasError as exc:
            message = f"{what}; the target could not be re-read ({exc}); {unknown}"
            return WriteResult(op, False, ErrorCode.TIMEOUT, message, old=old)
        if isinstance(current, FocasError):
            message = f"{what}; the target could not be re-read ({current}); {unknown}"
            return WriteResult(op, False, ErrorCode.TIMEOUT, message, old=old, cnc_time_ms=cnc_time)
        if target_io.holds(op, current):
            return WriteResult(op, True, old=old, read_back=current, cnc_time_ms=cnc_time,
                               note=f"{what}; a re-read shows the value was applied (it was not sent again)")
        message = f"{what}; a re-read shows {current!r}: the write did not take and was not repeated"
        return WriteResult(op, False, ErrorCode.NOT_APPLIED, message, old=old, read_back=current,
                           cnc_time_ms=cnc_time)

    async def _read_back(self, poller: MachinePoller, op: WriteOp) -> tuple[object, int]:
        """Read the target and every plan read it touches in one batch; publish those through the poller."""
        plan = poller.plan
        touching = reads_touching(plan, op.target) if plan is not None else []
        items = [target_io.read_item(op.target), *(read.item for read in touching)]
        results = await poller.session.batch(items)
        cnc_time = poller.cnc_time_ms()
        samples: list[Sample] = []
        for read, result in zip(touching, results[1:], strict=True):
            if not isinstance(result, FocasError):
                samples.extend(Sample(spec.name, value, spec.type, cnc_time)
                               for spec, value in metric_values(read, result))
        if samples:
            await poller.report(samples)
        first = results[0]
        if isinstance(first, FocasError):
            return first, cnc_time
        return target_io.current_value(op.target, first), cnc_time

    async def _wait_ready(self, deadline: float) -> MachinePoller:
        """The machine's poller once its CNC session is up; CommandRefused(unavailable) past `deadline`."""
        while True:
            poller = self._pollers.get(self.machine_id)
            if poller is not None and poller.session_up.is_set() and poller.session.connected:
                return poller
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise CommandRefused(ErrorCode.UNAVAILABLE, f"no CNC session for machine {self.machine_id} "
                                     f"within the reconnect deadline ({self._deadline_s():g} s); nothing was written")
            if poller is not None and not poller.session_up.is_set():
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(poller.session_up.wait(), min(remaining, 1.0))
            else:
                await asyncio.sleep(min(remaining, READY_POLL_S))


def _check_capability(poller: MachinePoller, op: WriteOp) -> None:
    operation = ("write_macro" if isinstance(op.target, MacroTarget)
                 else "write_param" if isinstance(op.target, ParamTarget) else "write_pmc")
    capabilities = poller.session.capabilities
    if not capabilities.can(operation):
        raise CommandRefused(ErrorCode.NOT_SUPPORTED, f"{op.target}: the {capabilities.transport} transport "
                             f"cannot {operation.replace('_', ' ')} (parameters need transport: packed)")
