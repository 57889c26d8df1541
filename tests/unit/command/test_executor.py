"""The write queue's flow against an in-memory session: lost answers are re-read, never re-sent."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from typing import Any

from edge.collect.plan import MachinePlan
from edge.command.dcmd import merge_adjacent, metric_target
from edge.command.errors import ErrorCode
from edge.command.executor import MachineWriteQueue
from edge.command.requests import WriteOp
from edge.config import AlarmsConfig, MachineConfig
from edge.focas import items as it
from edge.focas.errors import AccessDenied, FocasError, FocasTimeout
from edge.focas.model import Capabilities, PmcType
from edge.focas.targets import MacroTarget, ParamTarget, PmcTarget
from edge.samples import Sample
from edge.service.settings import poll_settings


class MemorySession:
    """Macros in a dict; `lose` makes the next write time out, applied or not."""

    def __init__(self) -> None:
        self.macros: dict[int, float] = {500: 1.0}
        self.connected = True
        self.sysinfo = None
        self.sent: list[tuple[int, float]] = []
        self.lose: str | None = None  # "applied" / "not_applied"
        self.write_error: FocasError | None = None
        self.capabilities = Capabilities("test", frozenset({"write_macro"}))

    async def read(self, item: it.ReadItem) -> Any:
        (result,) = await self.batch([item])
        if isinstance(result, FocasError):
            raise result
        return result

    async def batch(self, items: Sequence[it.ReadItem]) -> list[Any]:
        return [[self.macros.get(i.first)] for i in items if isinstance(i, it.ReadMacros)]

    async def write_macro(self, number: int, value: float) -> None:
        self.sent.append((number, value))
        if self.write_error is not None:
            raise self.write_error
        if self.lose != "not_applied":
            self.macros[number] = value
        if self.lose is not None:
            self.lose = None
            raise FocasTimeout("no complete answer within 0.5s")


class MemoryPoller:
    def __init__(self) -> None:
        self.session = MemorySession()
        self.session_up = asyncio.Event()
        self.session_up.set()
        self.plan = None
        self.reported: list[Sample] = []

    def cnc_time_ms(self) -> int:
        return int(time.time() * 1000)

    async def report(self, samples: Sequence[Sample]) -> None:
        self.reported.extend(samples)


def queue(poller: MemoryPoller, deadline: float = 0.3) -> MachineWriteQueue:
    return MachineWriteQueue("m1", {"m1": poller}, lambda: deadline)  # type: ignore[dict-item]


def macro(number: int, value: float) -> WriteOp:
    return WriteOp(MacroTarget(number, number), float(value))


async def test_success_reports_old_and_read_back() -> None:
    poller = MemoryPoller()
    (result,) = await queue(poller).run([macro(500, 2.5)], time.monotonic())
    assert result.ok and result.old == 1.0 and result.read_back == 2.5 and result.cnc_time_ms


async def test_lost_answer_of_an_applied_write_is_ok_after_reread() -> None:
    poller = MemoryPoller()
    poller.session.lose = "applied"
    (result,) = await queue(poller).run([macro(500, 2.5)], time.monotonic())
    assert result.ok and result.read_back == 2.5 and result.note and "not sent again" in result.note
    assert poller.session.sent == [(500, 2.5)]


async def test_lost_write_that_did_not_take_is_not_applied_and_not_repeated() -> None:
    poller = MemoryPoller()
    poller.session.lose = "not_applied"
    (result,) = await queue(poller).run([macro(500, 2.5)], time.monotonic())
    assert not result.ok and result.code is ErrorCode.NOT_APPLIED and result.read_back == 1.0
    assert poller.session.sent == [(500, 2.5)]


async def test_lost_write_with_no_session_back_is_a_timeout_of_unknown_outcome() -> None:
    poller = MemoryPoller()
    session = poller.session

    async def write_and_vanish(number: int, value: float) -> None:
        session.sent.append((number, value))
        session.connected = False
        poller.session_up.clear()
        raise FocasTimeout("no answer")

    session.write_macro = write_and_vanish  # type: ignore[method-assign]
    (result,) = await queue(poller, deadline=0.1).run([macro(500, 2.5)], time.monotonic())
    assert result.code is ErrorCode.TIMEOUT and result.message
    # What is known: the answer was lost and the target could not be re-read; not "nothing was written".
    assert "did not answer" in result.message and "could not be re-read" in result.message
    assert "unknown whether" in result.message and "nothing was written" not in result.message
    assert session.sent == [(500, 2.5)]


async def test_session_down_past_deadline_is_unavailable_and_nothing_is_sent() -> None:
    poller = MemoryPoller()
    poller.session_up.clear()
    started = time.monotonic()
    results = await queue(poller, deadline=0.1).run([macro(500, 2.5), macro(501, 1)], time.monotonic())
    assert [r.code for r in results] == [ErrorCode.UNAVAILABLE, ErrorCode.SKIPPED]
    assert 0.09 < time.monotonic() - started < 1.0 and poller.session.sent == []


async def test_cnc_error_stops_the_request() -> None:
    poller = MemoryPoller()
    poller.session.write_error = AccessDenied(17, "cnc_wrmacro")
    results = await queue(poller).run([macro(500, 2.5), macro(500, 3)], time.monotonic())
    assert [r.code for r in results] == [ErrorCode.ACCESS_DENIED, ErrorCode.SKIPPED]
    assert poller.session.sent == [(500, 2.5)]


async def test_queue_runs_requests_in_order_and_fails_waiting_ones_on_close() -> None:
    poller = MemoryPoller()
    writes = queue(poller)
    first = writes.submit([macro(500, 1)])
    second = writes.submit([macro(500, 2)])
    assert (await first)[0].ok and (await second)[0].ok
    assert poller.session.sent == [(500, 1), (500, 2)]
    poller.session_up.clear()
    stuck = writes.submit([macro(500, 3)])
    waiting = writes.submit([macro(500, 4)])
    await asyncio.sleep(0)
    await writes.close()
    assert (await stuck)[0].code is ErrorCode.SHUTTING_DOWN
    assert (await waiting)[0].code is ErrorCode.SHUTTING_DOWN


def test_dcmd_metric_names_map_to_targets_and_adjacent_pmc_merges() -> None:
    machine = MachineConfig.model_validate({"id": "m1", "host": "h", "poll": {
        "macros": ["500-502"], "pmc": [{"range": "D100-D107", "data_type": "word"}],
        "params": [{"number": 1825, "axis": 2}], "diags": [980]}})
    plan = MachinePlan.build(poll_settings(machine.poll, AlarmsConfig()))
    assert metric_target(plan, "Macro/501") == MacroTarget(501, 501)
    assert metric_target(plan, "PMC/D102") == PmcTarget("D", 102, 103, PmcType.WORD)
    assert metric_target(plan, "Param/1825/2") == ParamTarget(1825, 1825, 2)
    assert metric_target(plan, "Diag/980") is None and metric_target(plan, "Status/Run") is None
    ops = [WriteOp(PmcTarget("D", a, a + 1, PmcType.WORD), (a,)) for a in (100, 102, 106)]
    merged = merge_adjacent([*ops, WriteOp(MacroTarget(500, 500), 1.0)])
    assert [str(op.target) for op in merged] == ["pmc:D100-D103.word", "pmc:D106.word", "macro:500"]
    assert merged[0].value == (100, 102)
