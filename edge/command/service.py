"""Remote writes arriving over MQTT (Sparkplug DCMD, JSON cmd topic): the daemon's entry point.

Both inputs end in the same steps: validate (edge.command.requests, edge.command.limits), authorise
(edge.command.policy), audit, queue on the machine's write queue (edge.command.executor), reply (JSON)
or only audit and count (DCMD: Sparkplug 3.0 has no reply message). A request is checked completely
before any of it is queued: if one write of a list is refused, none is written.
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from itertools import groupby
from typing import TYPE_CHECKING

from edge.collect import MachinePlan, MachineSettings
from edge.command.audit import AuditLog, AuditRecord, utc_now
from edge.command.dcmd import merge_adjacent, metric_target
from edge.command.errors import CommandRefused, ErrorCode
from edge.command.executor import MachineWriteQueue
from edge.command.limits import check_limits
from edge.command.policy import RateLimiter, authorise
from edge.command.requests import RequestItem, WriteOp, make_op, parse_request
from edge.command.results import WriteResult, reply, request_error
from edge.command.settings import CommandSettings, WritePolicy
from edge.focas.model import SysInfo

if TYPE_CHECKING:
    from edge.collect import MachinePoller
    from edge.publish import CommandSource, Publisher

log = logging.getLogger(__name__)

Routed = tuple[MachineSettings, WriteOp]  # a write and the device (path) whose session carries it out


@dataclass
class _DcmdBatch:
    """DCMD metrics of one message, collected until the loop has dispatched them all."""

    device_id: str
    source: CommandSource
    metrics: list[tuple[str, object]] = field(default_factory=list)
    done: asyncio.Event = field(default_factory=asyncio.Event)


class CommandService:
    """Validates, authorises, audits, queues and answers writes; one instance per daemon."""

    def __init__(self, settings: CommandSettings, publisher: Publisher, pollers: Mapping[str, MachinePoller]) -> None:
        self.settings = settings
        self.publisher = publisher
        self.pollers = pollers
        self.audit = AuditLog(settings.state_dir)
        self._rate = RateLimiter()
        self._queues: dict[str, MachineWriteQueue] = {}
        self._dcmd: dict[tuple[str, str], _DcmdBatch] = {}
        self._counters: Counter[str] = Counter()
        self._closing = False

    @property
    def counters(self) -> dict[str, int]:
        """Writes by outcome (ok, each refusal/error code) and ignored DCMD metrics, for node metrics."""
        out = {"requests": 0, "writes_ok": 0, "writes_failed": 0, "writes_refused": 0, "dcmd_ignored": 0}
        out.update(self._counters)
        return out

    def reconfigure(self, settings: CommandSettings) -> None:
        self.settings = settings

    async def close(self) -> None:
        """Stop accepting commands; queued writes fail with shutting_down, the one in flight is cancelled."""
        self._closing = True
        for queue in list(self._queues.values()):
            await queue.close()
        self._queues.clear()
        self.audit.close()

    # ---- JSON ----------------------------------------------------------------------------------------
    async def on_json_command(self, device_id: str, payload: bytes, source: CommandSource) -> None:
        self._counters["requests"] += 1
        machine = self._machine(device_id)
        try:
            parsed = parse_request(payload, self.settings.max_payload_bytes)
        except CommandRefused as refusal:
            self._record(device_id, source, None, WriteResult.refused(None, refusal))
            await self.publisher.publish_json_reply(device_id, request_error(refusal.code, refusal.message), source)
            return
        if machine is None:
            results = self._refuse_all(device_id, parsed.items, source, CommandRefused(
                ErrorCode.UNKNOWN_MACHINE, f"no machine {device_id!r} is configured"))
        else:
            results = await self._run(machine, list(parsed.items), source)
        replies = [reply(item.id, item.target_text, result) for item, result in zip(parsed.items, results,
                                                                                     strict=True)]
        if parsed.is_list:
            # A list request gets a list reply, in request order.
            await self.publisher.publish_json_reply(device_id, replies, source)
        else:
            await self.publisher.publish_json_reply(device_id, replies[0], source)

    def _refuse_all(self, device_id: str, items: Sequence[RequestItem], source: CommandSource,
                    refusal: CommandRefused) -> list[WriteResult]:
        """One refusal for every item (each keeps its id and target in the reply), audited."""
        results = [WriteResult.refused(item.op, refusal) for item in items]
        for item, result in zip(items, results, strict=True):
            self._record(device_id, source, item, result)
        return results

    # ---- Sparkplug DCMD --------------------------------------------------------------------------------
    async def on_device_command(self, device_id: str, metric_name: str, value: object,
                                source: CommandSource) -> None:
        """One DCMD metric. The metrics of one message are gathered (the publisher hands them over in one
        loop turn) and run as one request, in order, with adjacent PMC elements merged."""
        key = (device_id, source.topic)
        batch = self._dcmd.get(key)
        if batch is None:
            batch = self._dcmd[key] = _DcmdBatch(device_id, source)
            asyncio.get_running_loop().call_soon(self._start_dcmd, key)
        batch.metrics.append((metric_name, value))
        await batch.done.wait()

    def on_device_command_refused(self, device_id: str, metric: str | None, code: str, reason: str,
                                  source: CommandSource) -> None:
        """A DCMD metric the publisher refused (unknown device or metric, read-only, wrong datatype, a
        number outside its datatype): one audit line and the outcome counters, like any other refusal."""
        try:
            error = ErrorCode(code)
        except ValueError:  # not expected: the publisher names ErrorCode values
            error = ErrorCode.MALFORMED
        refusal = CommandRefused(error, reason)
        item = RequestItem(0, None, None, None, metric, None, refusal)
        self._record(device_id, source, item, WriteResult.refused(None, refusal))

    def _start_dcmd(self, key: tuple[str, str]) -> None:
        batch = self._dcmd.pop(key)
        task = asyncio.get_running_loop().create_task(self._run_dcmd(batch))
        task.add_done_callback(lambda _t: batch.done.set())

    async def _run_dcmd(self, batch: _DcmdBatch) -> None:
        self._counters["requests"] += 1
        machine = self._machine(batch.device_id)
        items: list[RequestItem] = []
        for index, (name, value) in enumerate(batch.metrics):
            try:
                op = self._dcmd_op(machine, batch.device_id, name, value)
            except CommandRefused as refusal:
                self._counters["dcmd_ignored"] += 1
                log.warning("DCMD metric ignored machine=%s metric=%s code=%s reason=%s", batch.device_id,
                            name, refusal.code, refusal.message)
                items.append(RequestItem(index, None, None, None, name, value, refusal))
            else:
                items.append(RequestItem(index, None, None, op, op.text, op.reply_value()))
        if machine is None:
            for item in items:
                assert item.refused is not None
                self._record(batch.device_id, batch.source, item, WriteResult.refused(None, item.refused))
            return
        ops = [item.op for item in items if item.op is not None]
        if len(ops) == len(items):
            items = [RequestItem(i, None, None, op, op.text, op.reply_value())
                     for i, op in enumerate(merge_adjacent(ops))]
        await self._run(machine, items, batch.source)

    def _dcmd_op(self, machine: MachineSettings | None, device_id: str, name: str, value: object) -> WriteOp:
        if machine is None:
            raise CommandRefused(ErrorCode.UNKNOWN_MACHINE, f"no machine {device_id!r} is configured")
        target = metric_target(self._plan(machine), name)
        if target is None:
            raise CommandRefused(ErrorCode.UNKNOWN_METRIC, f"metric {name!r} has no write target in the "
                                 "machine's poll plan (only configured macros, PMC and parameters are writable)")
        try:
            return make_op(target, value)
        except ValueError as exc:  # PydanticCustomError is a ValueError
            raise CommandRefused(ErrorCode.WRONG_TYPE, f"metric {name!r}: {exc}") from None

    def _plan(self, machine: MachineSettings) -> MachinePlan:
        poller = self.pollers.get(machine.id)
        if poller is not None and poller.plan is not None:
            return poller.plan
        return MachinePlan.build(machine.poll)

    # ---- shared steps --------------------------------------------------------------------------------
    async def _run(self, machine: MachineSettings, items: Sequence[RequestItem],
                   source: CommandSource) -> list[WriteResult]:
        """Check every item; if all pass, admit (rate limit) and queue them; audit and count each."""
        policy = self.settings.policies[machine.id]
        checked = self._check(machine, policy, items)
        if isinstance(checked, tuple):
            results = await self._queue_and_wait(machine, policy, list(checked))
        else:
            results = checked
        for item, result in zip(items, results, strict=True):
            self._record(machine.id, source, item, result)
        return results

    def _check(self, machine: MachineSettings, policy: WritePolicy,
               items: Sequence[RequestItem]) -> tuple[Routed, ...] | list[WriteResult]:
        """The ops to write, each with the device whose session writes its path (and marked whether a bound
        applied), if every item may be written; else a result per item (the first refusal, the rest skipped)."""
        ops: list[Routed] = []
        for index, item in enumerate(items):
            refusal = item.refused
            if refusal is None and self._closing:
                refusal = CommandRefused(ErrorCode.SHUTTING_DOWN, "the daemon is stopping")
            if refusal is None:
                assert item.op is not None
                try:
                    device = self._path_device(machine, item.op.path)
                    ops.append((device, replace(item.op, bounded=authorise(item.op, policy))))
                    check_limits(item.op.target, self._sysinfo(device.id))
                except CommandRefused as exc:
                    refusal = exc
            if refusal is not None:
                return [WriteResult.refused(i.op, refusal) if n == index else WriteResult.skipped(i.op, index)
                        for n, i in enumerate(items)]
        return tuple(ops)

    def _path_device(self, machine: MachineSettings, path: int | None) -> MachineSettings:
        """The device whose session reads and writes `path` of the control behind `machine` (path 1 is the
        machine's own device, path n its `<id>-path<n>`); unknown_path beyond the configured paths."""
        if path is None or path == machine.path:
            return machine
        devices = machine.path_devices
        if path > len(devices):
            raise CommandRefused(ErrorCode.UNKNOWN_PATH, f"path {path}: machine {devices[0]!r} is configured with "
                                 f"{machine.paths} path(s) (`paths: {machine.paths}`); nothing was written")
        return self.settings.machines[devices[path - 1]]

    async def _queue_and_wait(self, machine: MachineSettings, policy: WritePolicy,
                              routed: list[Routed]) -> list[WriteResult]:
        """Admit the request, then run it in order: consecutive writes to one path as one job on that path's
        queue; after a failure the rest is skipped."""
        try:
            self._rate.admit(machine.id, len(routed), policy.rate_limit)
        except CommandRefused as refusal:
            return [WriteResult.refused(op, refusal) if n == 0 else WriteResult.skipped(op, 0)
                    for n, (_device, op) in enumerate(routed)]
        results: list[WriteResult] = []
        for device_id, group in groupby(routed, key=lambda pair: pair[0].id):
            ops = [op for _device, op in group]
            failed = next((n for n, result in enumerate(results) if not result.ok), None)
            if failed is not None:
                results.extend(WriteResult.skipped(op, failed) for op in ops)
                continue
            try:
                done = self._queue(device_id).submit(ops)
            except CommandRefused as refusal:
                first = len(results)
                results.extend(WriteResult.refused(op, refusal) if n == 0 else WriteResult.skipped(op, first)
                               for n, op in enumerate(ops))
                continue
            results.extend(await asyncio.shield(done))
        return results

    def _queue(self, machine_id: str) -> MachineWriteQueue:
        queue = self._queues.get(machine_id)
        if queue is None:
            def deadline() -> float:
                policy = self.settings.policies.get(machine_id)
                return policy.reconnect_deadline_s if policy is not None else 0.0

            queue = self._queues[machine_id] = MachineWriteQueue(machine_id, self.pollers, deadline)
        return queue

    def _record(self, machine_id: str, source: CommandSource, item: RequestItem | None,
                result: WriteResult) -> None:
        if result.ok:
            self._counters["writes_ok"] += 1
        elif result.code is not None and result.code.value in REFUSALS:
            self._counters["writes_refused"] += 1
        else:
            self._counters["writes_failed"] += 1
        self._counters[f"outcome/{result.outcome}"] += 1
        self.audit.write(AuditRecord(
            time=utc_now(), machine=machine_id, source=source.format, topic=source.topic,
            client_id=item.client if item is not None else None,
            request_id=item.id if item is not None else None,
            target=result.op.text if result.op is not None else (item.target_text if item else None),
            value=result.op.reply_value() if result.op is not None else (item.requested if item else None),
            old=result.old, new=result.read_back, outcome=result.outcome,
            message=result.note if result.ok else result.message))

    def _machine(self, machine_id: str) -> MachineSettings | None:
        return self.settings.machines.get(machine_id)

    def _sysinfo(self, machine_id: str) -> SysInfo | None:
        poller = self.pollers.get(machine_id)
        return poller.session.sysinfo if poller is not None else None


# Codes meaning "refused before the CNC was asked" (counted as writes_refused, not writes_failed).
REFUSALS = frozenset({ErrorCode.MALFORMED, ErrorCode.PAYLOAD_TOO_LARGE, ErrorCode.UNKNOWN_MACHINE,
                      ErrorCode.UNKNOWN_METRIC, ErrorCode.DISABLED, ErrorCode.INVALID_TARGET,
                      ErrorCode.NOT_ALLOWED, ErrorCode.WRONG_TYPE, ErrorCode.OUT_OF_BOUNDS,
                      ErrorCode.RATE_LIMITED, ErrorCode.QUEUE_FULL, ErrorCode.SKIPPED,
                      ErrorCode.SHUTTING_DOWN})
