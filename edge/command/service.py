"""Remote writes (Sparkplug DCMD, the JSON cmd topic, OPC UA): the daemon's entry point.

Every input ends in `execute`, the same steps: validate (edge.command.requests, edge.command.limits), authorise
(edge.command.policy), audit, queue on the machine's write queue (edge.command.executor), reply (JSON)
or only audit and count (DCMD: Sparkplug 3.0 has no reply message). A request is checked completely
before any of it is queued: if one write of a list is refused, none is written.
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import replace
from itertools import groupby
from typing import TYPE_CHECKING

from edge.collect import MachinePlan, MachineSettings
from edge.command.audit import AuditLog, AuditRecord, utc_now
from edge.command.dcmd import merge_adjacent, metric_target
from edge.command.errors import CommandRefused, ErrorCode
from edge.command.executor import MachineWriteQueue
from edge.command.limits import check_limits
from edge.command.policy import RateLimiter, authorise
from edge.command.refusal_summary import summary_record
from edge.command.requests import MAX_WRITES_PER_REQUEST, ParsedRequest, RequestItem, WriteOp, make_op, parse_request
from edge.command.results import WriteResult, reply, request_error
from edge.command.settings import CommandSettings, WritePolicy
from edge.focas.model import SysInfo

if TYPE_CHECKING:
    from edge.collect import MachinePoller
    from edge.publish import CommandSource, DeviceCommands, Publisher

log = logging.getLogger(__name__)

Routed = tuple[MachineSettings, WriteOp]  # a write and the device (path) whose session carries it out


class CommandService:
    """Validates, authorises, audits, queues and answers writes; one instance per daemon."""

    def __init__(self, settings: CommandSettings, publisher: Publisher, pollers: Mapping[str, MachinePoller]) -> None:
        self.settings = settings
        self.publisher = publisher
        self.pollers = pollers
        self.audit = AuditLog(settings.state_dir, settings.audit_max_bytes, settings.audit_keep)
        self._rate = RateLimiter()
        self._queues: dict[str, MachineWriteQueue] = {}
        self._counters: Counter[str] = Counter()
        self._closing = False

    @property
    def counters(self) -> dict[str, int]:
        """Writes by outcome (ok, each refusal/error code) and ignored DCMD metrics, for node metrics."""
        out = {"requests": 0, "writes_ok": 0, "writes_failed": 0, "writes_refused": 0, "dcmd_ignored": 0}
        out.update(self._counters)
        out["audit_lines_unwritten"] = self.audit.unwritten
        return out

    def reconfigure(self, settings: CommandSettings) -> None:
        self.settings = settings
        self.audit.max_bytes, self.audit.keep = settings.audit_max_bytes, settings.audit_keep

    async def close(self) -> None:
        """Stop accepting commands; queued writes fail with shutting_down, the one in flight is cancelled."""
        self._closing = True
        for queue in list(self._queues.values()):
            await queue.close()
        self._queues.clear()
        self.audit.close()

    # ---- the one entry point ---------------------------------------------------------------------------
    async def execute(self, device_id: str, items: Sequence[RequestItem], source: CommandSource) -> list[WriteResult]:
        """Carry out one request, whatever it came from (JSON, Sparkplug DCMD, OPC UA): every item checked
        (policy, bounds on the number the CNC holds), then queued, read back, audited and counted; a result
        per item, in order."""
        self._counters["requests"] += 1
        machine = self._machine(device_id)
        if machine is None:
            return self._refuse_all(device_id, items, source, CommandRefused(
                ErrorCode.UNKNOWN_MACHINE, f"no machine {device_id!r} is configured"))
        return await self._run(machine, items, source)

    async def write_metrics(self, device_id: str, metrics: Sequence[tuple[str, object]], source: CommandSource,
                            client: str | None = None) -> list[WriteResult]:
        """Writes named by metric (DCMD, OPC UA): each name resolved to the CNC target behind it in the
        machine's poll plan, adjacent PMC elements merged, then `execute`."""
        return await self.execute(device_id, self._metric_items(device_id, metrics, source, client), source)

    def refuse_metric(self, device_id: str, metric: str | None, code: str, reason: str, source: CommandSource,
                      client: str | None = None) -> None:
        """A metric write refused before it became a request (unknown device or metric, read-only, wrong
        datatype, a number outside its datatype): one audit line and the outcome counters, like any other
        refusal."""
        refusal = CommandRefused(_code(code), reason)
        item = RequestItem(0, None, client, None, metric, None, refusal)
        self._record(device_id, source, item, WriteResult.refused(None, refusal))

    # ---- JSON ----------------------------------------------------------------------------------------
    async def on_json_command(self, device_id: str, payload: bytes, source: CommandSource) -> None:
        """One request from the cmd topic: exactly one reply and its audit line(s), whatever it holds."""
        try:
            parsed = parse_request(payload, self.settings.max_payload_bytes)
        except CommandRefused as refusal:
            self._counters["requests"] += 1
            self._record(device_id, source, None, WriteResult.refused(None, refusal))
            await self.publisher.publish_json_reply(device_id, request_error(refusal.code, refusal.message), source)
            return
        results = await self._json_results(device_id, parsed, source)
        replies = [reply(item.id, item.target_text, result) for item, result in zip(parsed.items, results,
                                                                                     strict=True)]
        if parsed.is_list:
            # A list request gets a list reply, in request order.
            await self.publisher.publish_json_reply(device_id, replies, source)
        else:
            await self.publisher.publish_json_reply(device_id, replies[0], source)

    async def _json_results(self, device_id: str, parsed: ParsedRequest, source: CommandSource) -> list[WriteResult]:
        if parsed.refused is not None:  # too many writes: each id answered, one audit line
            self._counters["requests"] += 1
            return self._refuse_command(device_id, source, parsed.items, parsed.refused)
        try:
            return await self.execute(device_id, parsed.items, source)
        except Exception as exc:  # a bug must not cost the reply and the audit line
            return self._internal_error(device_id, source, parsed.items, exc)

    def _refuse_all(self, device_id: str, items: Sequence[RequestItem], source: CommandSource,
                    refusal: CommandRefused) -> list[WriteResult]:
        """One refusal for every item (each keeps its id and target in the reply), audited."""
        results = [WriteResult.refused(item.op, refusal) for item in items]
        self._audit_results(device_id, source, items, results)
        return results

    def _refuse_command(self, device_id: str, source: CommandSource, items: Sequence[RequestItem],
                        refusal: CommandRefused) -> list[WriteResult]:
        """A command refused as a whole (over a cap): every item answered with `refusal`, one audit line."""
        results = [WriteResult.refused(item.op, refusal) for item in items]
        self._audit_refused(device_id, source, items, results)
        return results

    def _internal_error(self, device_id: str, source: CommandSource, items: Sequence[RequestItem],
                        exc: Exception) -> list[WriteResult]:
        """The gateway failed handling a command (a bug): logged with its traceback, answered and audited."""
        log.exception("write command failed inside the gateway machine=%s topic=%s", device_id, source.topic)
        message = (f"the gateway failed handling this command ({type(exc).__name__}: {exc}); see its log. A write "
                   "already queued may have reached the CNC: read the target before retrying")
        results = [WriteResult(item.op, False, ErrorCode.INTERNAL_ERROR, message) for item in items]
        self._audit_refused(device_id, source, items, results)
        return results

    # ---- Sparkplug DCMD --------------------------------------------------------------------------------
    async def on_device_commands(self, commands: DeviceCommands, source: CommandSource) -> None:
        """One DCMD message, one request: capped like a JSON request (bytes, writes), all-or-nothing (a metric
        the publisher refused means none is written), in order, adjacent PMC elements merged. Sparkplug has no
        reply: the outcome is the audit (one line when refused), the counters and DDATA."""
        device_id = commands.device_id
        metrics = [(name, value) for name, value in commands.writes]
        try:
            over = self._dcmd_over_limit(commands)
            if over is not None:
                self._counters["requests"] += 1
                items = [RequestItem(i, None, None, None, name, value, over) for i, (name, value) in enumerate(metrics)]
                items += [RequestItem(len(items) + i, None, None, None, r.metric, None, over)
                          for i, r in enumerate(commands.refused)]
                items = items or [RequestItem(0, None, None, None, None, None, over)]
                self._refuse_command(device_id, source, items, over)
                return
            items = self._metric_items(device_id, metrics, source, None)
            if commands.refused:
                self._counters["requests"] += 1
                refused = [RequestItem(len(items) + i, None, None, None, r.metric, None,
                                       CommandRefused(_code(r.code), r.reason)) for i, r in enumerate(commands.refused)]
                everything = refused + items
                results = [WriteResult.refused(item.op, item.refused) if item.refused is not None
                           else WriteResult.skipped(item.op, 0) for item in everything]
                self._audit_refused(device_id, source, everything, results)
                return
            await self.execute(device_id, items, source)
        except Exception as exc:  # a bug must not cost the audit line
            self._internal_error(device_id, source, [RequestItem(0, None, None, None, None, None)], exc)

    def _dcmd_over_limit(self, commands: DeviceCommands) -> CommandRefused | None:
        """The JSON caps for a DCMD: at most max_payload_bytes and MAX_WRITES_PER_REQUEST metrics."""
        if commands.metric_count == 0:
            return CommandRefused(ErrorCode.MALFORMED, "a DCMD without metrics; nothing to write")
        limit = self.settings.max_payload_bytes
        if commands.payload_bytes > limit:
            return CommandRefused(ErrorCode.PAYLOAD_TOO_LARGE, f"DCMD is {commands.payload_bytes} bytes; at most "
                                  f"{limit} are accepted (writes.max_payload_bytes); nothing was written")
        if commands.metric_count > MAX_WRITES_PER_REQUEST:
            return CommandRefused(ErrorCode.MALFORMED, f"{commands.metric_count} metrics in one DCMD; at most "
                                  f"{MAX_WRITES_PER_REQUEST}; nothing was written")
        return None

    def _metric_items(self, device_id: str, metrics: Sequence[tuple[str, object]], source: CommandSource,
                      client: str | None) -> list[RequestItem]:
        machine = self._machine(device_id)
        items: list[RequestItem] = []
        for index, (name, value) in enumerate(metrics):
            try:
                op = self._dcmd_op(machine, device_id, name, value)
            except CommandRefused as refusal:
                if source.format == "sparkplug":
                    self._counters["dcmd_ignored"] += 1
                log.warning("metric write ignored source=%s machine=%s metric=%s code=%s reason=%s", source.format,
                            device_id, name, refusal.code, refusal.message)
                items.append(RequestItem(index, None, client, None, name, value, refusal))
            else:
                items.append(RequestItem(index, None, client, op, op.text, op.reply_value()))
        ops = [item.op for item in items if item.op is not None]
        if machine is not None and len(ops) == len(items):
            items = [RequestItem(i, None, client, op, op.text, op.reply_value())
                     for i, op in enumerate(merge_adjacent(ops))]
        return items

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
        self._audit_results(machine.id, source, items, results)
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

    def _audit_results(self, machine_id: str, source: CommandSource, items: Sequence[RequestItem],
                       results: Sequence[WriteResult]) -> None:
        """A line per write; but a DCMD none of whose writes was sent is one line (it can hold 64 metrics)."""
        unsent = all(result.code in REFUSALS for result in results)
        if source.format == "sparkplug" and unsent and len(items) > 1:
            self._audit_refused(machine_id, source, items, results)
            return
        for item, result in zip(items, results, strict=True):
            self._record(machine_id, source, item, result)

    def _audit_refused(self, machine_id: str, source: CommandSource, items: Sequence[RequestItem],
                       results: Sequence[WriteResult]) -> None:
        """Every write counted, the command audited in one line (edge.command.refusal_summary)."""
        for result in results:
            self._count(result)
        self.audit.write(summary_record(machine_id, source.format, source.topic, items, results))

    def _count(self, result: WriteResult) -> None:
        if result.ok:
            self._counters["writes_ok"] += 1
        elif result.code is not None and result.code.value in REFUSALS:
            self._counters["writes_refused"] += 1
        else:
            self._counters["writes_failed"] += 1
        self._counters[f"outcome/{result.outcome}"] += 1

    def _record(self, machine_id: str, source: CommandSource, item: RequestItem | None,
                result: WriteResult) -> None:
        self._count(result)
        self.audit.write(AuditRecord(
            time=utc_now(), machine=machine_id, source=source.format, topic=source.topic,
            client_id=item.client if item is not None else None,
            request_id=item.id if item is not None else None,
            target=result.op.text if result.op is not None else (item.target_text if item else None),
            value=result.op.reply_value() if result.op is not None else (item.requested if item else None),
            old=result.old, new=result.read_back, outcome=result.outcome,
            message=result.note if result.ok else result.message))

    def writable_metrics(self, device_id: str, metrics: Sequence[str]) -> frozenset[str]:
        """Which of `metrics` have a CNC target the machine's write policy covers (whatever the value): what
        an OPC UA node's AccessLevel shows. A write itself is still checked in full by `execute`."""
        machine = self._machine(device_id)
        policy = self.settings.policies.get(device_id)
        if machine is None or policy is None or not policy.enabled:
            return frozenset()
        plan = self._plan(machine)
        covered = set()
        for name in metrics:
            target = metric_target(plan, name)
            if target is not None and any(rule.pattern.covers(target) for rule in policy.allow):
                covered.add(name)
        return frozenset(covered)

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


def _code(text: str) -> ErrorCode:
    """The reply code the publisher named for a refused metric (malformed if it named none we know)."""
    try:
        return ErrorCode(text)
    except ValueError:
        return ErrorCode.MALFORMED
