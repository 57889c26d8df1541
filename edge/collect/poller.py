"""One machine's polling loop: connect, read static data, then tick until the session breaks.

A tick batches every due group plus the CNC clock into ONE request (one network round trip), turns
the results into samples stamped with CNC time, and hands what changed to the sink. Between ticks, a
few clock-only reads timed by edge.collect.clock_probe keep the CNC-vs-gateway offset to milliseconds.
A failed item only marks its own metrics bad; a function the control does not have (EW_FUNC/EW_NOOPT) is
dropped from this machine's plan (a WARNING the first time) and tried again after `poll.retry_dropped` and
at every reconnect, since one transient answer must not end a data stream. A broken session ends in
device_offline, backoff, and a fresh birth with the full state on recovery.

What a tick sends, prepared once per plan, is edge.collect.tick_batch; the counters are edge.collect.stats.

Over 600 lines on purpose: the loop's states (connect, static reads, ticks, clock probes, dropped-function
retries, offline) share one session and one set of counters, and the hot tick path reads them as local
attributes; what could leave without crossing that state already has (tick_batch, stats, clock_feed,
plant_state, execution, utilisation).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import random
import time
from collections.abc import Callable, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from itertools import compress
from operator import is_not
from pathlib import Path
from typing import Any, Protocol

from edge.collect import plan as pl
from edge.collect.alarms import ActiveAlarmProjection, AlarmHistoryDedup, WatermarkStore, history_event
from edge.collect.answer_time import AnswerTime
from edge.collect.axis_numbers import per_axis_numbers
from edge.collect.changes import ChangeDetector
from edge.collect.clock_feed import ClockFeed
from edge.collect.minute_timers import MinuteTimers
from edge.collect.path_check import PATH_COUNT, PathCheck, connect_error
from edge.collect.plant_state import SPECS as PLANT_STATE_SPECS
from edge.collect.plant_state import PlantState
from edge.collect.settings import MachineSettings
from edge.collect.start_gate import StartGate, StartTicket
from edge.collect.stats import PollerStats
from edge.collect.tick_batch import ReadKind, TickBatch
from edge.collect.tickgrid import TickGrid
from edge.focas import items as it
from edge.focas.connect import open_session
from edge.focas.errors import FocasError, FunctionNotAvailable, NotSupported
from edge.focas.model import ActiveAlarm, AlarmHistoryEntry, StatInfo
from edge.focas.outage import ConnectOutage, backoff_s
from edge.focas.session import CncSession
from edge.samples import MetricSpec, MetricType, Quality, Sample

log = logging.getLogger(__name__)

DROPPED_FUNCTIONS = MetricSpec("Plan/DroppedFunctions", MetricType.STRING,
                               description="functions this control does not answer (EW_FUNC/EW_NOOPT)")


class DeviceSink(Protocol):
    """Where a machine's data goes (the Publisher implements it)."""

    async def device_online(self, device_id: str, specs: Sequence[MetricSpec],
                            samples: Sequence[Sample]) -> None: ...

    async def device_data(self, device_id: str, samples: Sequence[Sample]) -> None: ...

    async def device_events(self, device_id: str, events: Sequence[Sample]) -> None: ...

    async def device_offline(self, device_id: str) -> None: ...


@dataclass(slots=True)
class TickResult:
    samples: list[Sample]
    events: list[Sample]  # alarm raise/clear
    history: list[AlarmHistoryEntry]  # new alarm-history entries, oldest first


_NOT_IN_TICK = frozenset({pl.Group.ACTIVE_ALARMS, pl.Group.STATIC})  # read on change / once per session
_NOTHING = object()  # no previous result (compares unequal to any result)
PROBE_ITEMS = (it.ReadClock(),)  # a clock-only read (one stable tuple: the client reuses its request)


SessionFactory = Callable[[MachineSettings], CncSession]


def default_session(machine: MachineSettings) -> CncSession:
    timeouts = machine.timeouts
    extra: dict[str, Any] = {} if machine.max_subpackets is None else {"max_subpackets": machine.max_subpackets}
    if machine.path != 1:
        extra["path"] = machine.path
    return open_session(machine.transport, machine.endpoint, fwlib_host=machine.fwlib_host,
                        timeout=timeouts.request_s, connect_timeout=timeouts.connect_s,
                        backoff_initial=timeouts.backoff_initial_s, backoff_max=timeouts.backoff_max_s, **extra)


class MachinePoller:
    """Owns one machine's session and polling task; `run()` until cancelled, `close()` after."""

    # A poller has more attributes than an instance dict shares keys for (30): its own dict was ~1.5 kB.
    __slots__ = ("_alarms", "_answer_time", "_batches", "_batches_plan", "_by_due", "_changes", "_clock",
                 "_dropped", "_full_plan", "_grid", "_history", "_jitter_s", "_last_raw", "_metric_groups",
                 "_outage", "_paths", "_plan", "_read_at_by_due", "_retry_at", "_retrying", "_session_up",
                 "_start", "_unsupported_ops", "_up", "_warned_dropped", "clock", "last_error", "last_progress",
                 "machine", "online", "online_changed_at", "plant_state", "session", "sink", "stats")

    def __init__(self, machine: MachineSettings, sink: DeviceSink, state_dir: Path,
                 session_factory: SessionFactory = default_session, jitter_s: float = 1.0,
                 grid: TickGrid | None = None, start_gate: StartGate | None = None) -> None:
        self.machine = machine
        self.sink = sink
        self.session = session_factory(machine)
        self.stats = PollerStats()
        self.online = False
        self.online_changed_at = time.time()  # wall time `online` last changed (the status page's "since")
        self.last_error = ""  # the last connect, session or read error, for the status page
        self._outage = ConnectOutage(f"machine={machine.id}", log)  # a switched-off CNC: not a line per retry
        self.last_progress = time.monotonic()
        # Wall time of the last answered batch, by the set of groups it read (one dict store a tick; read_at
        # turns it into per group times when the status page asks).
        self._read_at_by_due: dict[AbstractSet[pl.Group], float] = {}
        self._metric_groups: tuple[pl.MachinePlan | None, dict[str, pl.Group]] = (None, {})
        self._clock = ClockFeed(machine.id, machine.zone, machine.max_skew_s)
        self.clock = self._clock.tracker
        self._answer_time = AnswerTime()  # when the CNC answered a tick, for its stamp
        self._jitter_s = jitter_s
        self._start = StartTicket(start_gate)  # held from the session's connect to the DBIRTH
        self._changes = ChangeDetector()
        self._alarms = ActiveAlarmProjection()
        history_store = WatermarkStore(state_dir, machine.id)
        self._history = AlarmHistoryDedup(history_store)
        self._dropped: dict[str, float] = {}  # operation -> monotonic time it was dropped (this session)
        self._retry_at = math.inf  # when the earliest drop is due to be tried again (one compare per tick)
        self._retrying: set[str] = set()  # put back in the plan, not answered yet (still listed as dropped)
        self._unsupported_ops: set[str] = set()  # planned, but the transport has no form for them (never retried)
        self._warned_dropped: set[str] = set()  # drops already logged at WARNING (once per daemon run)
        self._full_plan: pl.MachinePlan | None = None  # this session's plan before any drop
        self._plan: pl.MachinePlan | None = None
        self._grid = grid or TickGrid()
        self._batches: dict[frozenset[pl.Group], TickBatch] = {}  # by the groups read in the tick
        self._by_due: dict[AbstractSet[pl.Group], TickBatch] = {}  # by the groups the schedule said were due
        self._batches_plan: pl.MachinePlan | None = None
        # Per read of the current plan (by index in plan.reads), its last good result: a read whose
        # result is that very object again did not move (the client hands an unchanged answer's value back).
        self._last_raw: list[object] = []
        self._up = False  # the CNC session is up and the device is born
        self._session_up: asyncio.Event | None = None  # made when first asked for (~0.7 kB: its deque)
        self._paths = PathCheck(machine)
        self.plant_state = PlantState(machine.id, machine.zone, state_dir)  # availability, utilisation

    @property
    def session_up(self) -> asyncio.Event:
        """Set while the CNC session is up and the device is born (what a write waits for)."""
        event = self._session_up
        if event is None:
            event = self._session_up = asyncio.Event()
            if self._up:
                event.set()
        return event

    def _set_up(self, up: bool) -> None:
        self._up = up
        if self._session_up is not None:
            if up:
                self._session_up.set()
            else:
                self._session_up.clear()

    @property
    def machine_id(self) -> str:
        return self.machine.id

    @property
    def plan(self) -> pl.MachinePlan | None:
        """This session's plan (metric names, which reads feed them); None before the first connect."""
        return self._plan

    @property
    def dropped(self) -> list[str]:
        """Operations this control refused (EW_FUNC/EW_NOOPT/not supported), no longer polled."""
        return sorted(self._dropped.keys() | self._retrying | self._unsupported_ops)

    @property
    def active_alarms(self) -> list[ActiveAlarm]:
        return self._alarms.active

    def last_values(self) -> dict[str, Sample]:
        """The last value published for each metric."""
        return self._changes.last_reported()

    @property
    def read_at(self) -> dict[pl.Group, float]:
        """Wall time each poll group was last read by a batch that answered, this session (a value's age)."""
        out: dict[pl.Group, float] = {}
        for groups, when in self._read_at_by_due.items():
            for group in groups:
                if when > out.get(group, 0.0):
                    out[group] = when
        return out

    def metric_groups(self) -> dict[str, pl.Group]:
        """Metric name -> the poll group that reads it, for this session's plan (built once per plan)."""
        plan = self._full_plan
        if self._metric_groups[0] is not plan:
            groups = {} if plan is None else {m.name: r.group for r in plan.reads for m in r.metrics}
            self._metric_groups = (plan, groups)
        return self._metric_groups[1]

    def cnc_time_ms(self) -> int:
        """Now, as the CNC's clock says (gateway time while the CNC clock is untrusted)."""
        return self.clock.source_time_ms(time.monotonic(), time.time())

    async def report(self, samples: Sequence[Sample]) -> None:
        """Publish values learned outside a tick (a write's read-back) through change detection."""
        changed = self._changes.filter(samples)
        # These metrics' reported values moved outside a tick: the next tick offers every value it reads again.
        self._last_raw[:] = [_NOTHING] * len(self._last_raw)
        if changed and self.online:
            await self.sink.device_data(self.machine_id, changed)

    async def _publish_born(self, samples: Sequence[Sample]) -> None:
        """Publish while the device is born; before that, the birth will carry the values (not filtered away)."""
        if self.online and (changed := self._changes.filter(samples)):
            await self.sink.device_data(self.machine_id, changed)

    # ---- lifecycle -----------------------------------------------------------------------------------
    async def run(self) -> None:
        """Connect (with backoff), poll until the session breaks, go offline, repeat. Cancel to stop."""
        # The utilisation minute publish, on the loop's shared minute timer (not a task a machine), ended with
        # this task (a try, not a done callback on this task: its closure was ~0.4 kB a machine).
        minutes = MinuteTimers.for_loop().start(self.plant_state, self.cnc_time_ms, self._publish_born)
        try:
            await asyncio.sleep(random.uniform(0, self._jitter_s))  # a fleet must not poll in lock-step
            while True:
                await self._connect()
                try:
                    await self._start.acquire()  # the start's reads and birth: at most K machines at a time
                    await self._poll_session()
                except FocasError as exc:
                    log.warning("session lost machine=%s error=%s", self.machine_id, exc)
                    self.last_error = f"session lost: {exc}"
                finally:
                    self._start.release()
                    await self._go_offline()
                    await self.session.reset()
        finally:
            minutes.cancel()

    async def close(self) -> None:
        """Save the utilisation counters, send the close PDU (the run task must already be cancelled)."""
        self.plant_state.close(self.cnc_time_ms())
        with contextlib.suppress(Exception):
            await self.session.close()

    async def _connect(self) -> None:
        """Connect, retrying a FocasError after edge.focas.outage.backoff_s (the outage logged, not each try)."""
        timeouts = self.machine.timeouts
        failures = 0
        while True:
            try:
                await self.session.connect()
                break
            except FocasError as error:
                failures += 1
                delay = backoff_s(failures, timeouts.backoff_initial_s, timeouts.backoff_max_s)
                self.last_progress = time.monotonic()
                reason = connect_error(self.machine, error)
                self.last_error = f"connect failed: {reason}"
                self._outage.failed(reason, delay)
            await asyncio.sleep(delay)  # outside the handler: the error and its traceback are gone
        self.stats.connects += 1
        self.last_progress = time.monotonic()
        log.info("connected machine=%s endpoint=%s model=%s", self.machine_id, self.machine.endpoint,
                 self.session.sysinfo.model_name if self.session.sysinfo else "?")
        self._outage.connected()

    async def _go_offline(self) -> None:
        self._set_up(False)
        unavailable = self.plant_state.offline(self.cnc_time_ms())  # counted OFFLINE even if never born
        if not self.online:
            return
        self.online = False
        self.online_changed_at = time.time()
        self.stats.disconnects += 1
        with contextlib.suppress(Exception):  # before the death: a dead device carries no data
            await self.sink.device_data(self.machine_id, self._changes.filter(unavailable))
        with contextlib.suppress(Exception):
            await self.sink.device_offline(self.machine_id)

    # ---- one session ---------------------------------------------------------------------------------
    async def _poll_session(self) -> None:
        static = await self._read_static()
        self._read_at_by_due = {pl.group_set((pl.Group.STATIC,)): time.time()}
        paths = await self._paths.count(self.session)
        plan = pl.MachinePlan.build(self.machine.poll, static)
        for operation in self._unsupported(plan):
            plan = plan.without(operation)
        self._full_plan = self._plan = plan
        self._dropped.clear()  # a new session asks for every function again
        self._retry_at = math.inf
        self._retrying.clear()
        schedule = pl.Schedule(plan.periods)
        schedule.start(time.monotonic())
        schedule.due(time.monotonic())  # static group already read above
        self._changes = ChangeDetector(plan.deadbands(), [spec.name for spec in self._birth_specs(plan)])
        self._last_raw = [_NOTHING] * len(plan.reads)
        self._clock.new_session()
        self._answer_time.reset()
        first = await self._tick(plan, pl.group_set(plan.periods))
        specs = self._birth_specs(plan, with_paths=paths is not None)
        extra = [*self._static_samples(plan, first.samples), self._dropped_sample(first.samples)]
        extra += self.plant_state.birth_samples(extra[-1].timestamp_ms)
        if paths is not None:
            extra.append(Sample(PATH_COUNT.name, paths, PATH_COUNT.type, extra[-1].timestamp_ms))
        born = [*first.samples, *self._changes.filter(extra)]
        await self.sink.device_online(self.machine_id, specs, born)
        self.online = True
        self.online_changed_at = time.time()
        self._set_up(True)
        self._start.release()
        if first.events or first.history:
            await self._emit_events(first.events, first.history)
        del first, specs, extra, born  # the loop keeps this frame for the session: not the births' samples
        fastest = min(plan.periods.values())
        while True:
            next_due = schedule.next_due() or time.monotonic() + fastest
            if (probe_at := self._probe_before(next_due)) is not None:  # no coroutine on the ticks without one
                await self._probe_clock(probe_at)
                continue
            await self._grid.wake_at(next_due)
            started = time.monotonic()
            groups = schedule.due(started)
            self.stats.skipped = schedule.skipped
            if not groups:
                continue
            if started >= self._retry_at:
                self._retry_dropped(started)
            plan = self._plan or plan
            tick = await self._tick(plan, groups)
            if tick.samples:  # already change-filtered
                await self.sink.device_data(self.machine_id, tick.samples)
            if tick.events or tick.history:
                await self._emit_events(tick.events, tick.history)
            elapsed = time.monotonic() - started
            if elapsed > fastest:
                self.stats.overruns += 1

    @staticmethod
    def _birth_specs(plan: pl.MachinePlan, with_paths: bool = True) -> list[MetricSpec]:
        """The metrics a session's DBIRTH declares (the path count only where the control answered it)."""
        return [*plan.metrics(), DROPPED_FUNCTIONS, *PLANT_STATE_SPECS, *((PATH_COUNT,) if with_paths else ())]

    async def _read_static(self) -> pl.StaticInfo:
        items = [it.ReadAxisNames(), it.ReadSpindleNames()]
        results = await self.session.batch(items)
        axes = results[0] if isinstance(results[0], list) else []
        spindles = results[1] if isinstance(results[1], list) else []
        for item, result in zip(items, results, strict=True):
            if isinstance(result, FunctionNotAvailable | NotSupported):  # a control without it: nothing to name
                log.info("static read failed machine=%s error=%s", self.machine_id, result)
            elif isinstance(result, FocasError):  # this session publishes no metric named by it: say so
                self._count_failure(item.operation, result)
            else:
                self._answered(item.operation)
        per_axis = await per_axis_numbers(self.session, self.machine)
        return pl.StaticInfo(self.session.sysinfo, tuple(str(a) for a in axes),
                             tuple(str(s) for s in spindles), per_axis)

    def _static_samples(self, plan: pl.MachinePlan, samples: Sequence[Sample]) -> list[Sample]:
        """Values of the once-per-session metrics (sysinfo), stamped like the first tick."""
        sysinfo = self.session.sysinfo
        when = samples[0].timestamp_ms if samples else int(time.time() * 1000)
        out: list[Sample] = []
        for read in plan.reads:
            if read.group is pl.Group.STATIC and isinstance(read.item, it.ReadSysInfo) and sysinfo is not None:
                out.extend(Sample(spec.name, value, spec.type, when) for spec, value in pl.metric_values(read, sysinfo))
        return out

    def _unsupported(self, plan: pl.MachinePlan) -> list[str]:
        """Planned reads this machine's transport cannot do: warned once, and listed in Plan/DroppedFunctions."""
        capabilities = self.session.capabilities
        missing = sorted({r.item.operation for r in plan.reads if not capabilities.can(r.item.operation)})
        for operation in missing:
            if operation not in self._unsupported_ops:
                log.warning("not polled machine=%s operation=%s reason=not supported by the %s transport",
                            self.machine_id, operation, capabilities.transport)
        self._unsupported_ops = set(missing)
        return missing

    def _batch_for(self, plan: pl.MachinePlan, groups: AbstractSet[pl.Group]) -> TickBatch:
        """The reads of the due groups plus the clock, built once per plan and combination of groups."""
        if self._batches_plan is not plan:
            self._batches.clear()
            self._by_due.clear()
            self._batches_plan = plan
            self._last_raw = [_NOTHING] * len(plan.reads)  # indices changed: every read counts as moved
        batch = self._by_due.get(groups)  # the schedule hands out one frozenset per combination
        if batch is not None:
            return batch
        key = pl.group_set(groups - _NOT_IN_TICK)  # combinations that differ only there share one batch
        batch = self._batches.get(key)
        if batch is None:
            reads = plan.reads_for(key)
            index = {id(read): i for i, read in enumerate(plan.reads)}
            batch = TickBatch.shared(reads, [index[id(read)] for read in reads])
            self._batches[key] = batch
        self._by_due[pl.group_set(groups)] = batch
        return batch

    async def _tick(self, plan: pl.MachinePlan, groups: AbstractSet[pl.Group]) -> TickResult:
        """One batched round trip for the due groups; the samples returned are the changes only."""
        batch = self._batch_for(plan, groups)
        wall_before, mono_before = time.time(), time.monotonic()
        results = await self.session.batch(batch.items)
        mono_after, wall_after = time.monotonic(), time.time()
        self.last_progress = mono_after
        self.stats.ticks += 1
        if pl.Group.STATUS in groups:
            self.stats.status_reads += 1
        rtt = mono_after - mono_before
        self.stats.record_cycle(rtt)
        mid_mono = (mono_before + mono_after) / 2
        mid_wall = (wall_before + wall_after) / 2
        self._read_at_by_due[groups] = mid_wall
        clock_observed = self._observe_clock(results[-1], mid_mono, mid_wall, rtt / 2)
        answered = self._answer_time.half_rtt(rtt)  # not later for the gateway's own delay (answer_time)
        timestamp = self.clock.source_time_ms(mono_before + answered, wall_before + answered)

        samples: list[Sample] = []
        events: list[Sample] = []
        alarm_status: int | None = None
        status: StatInfo | None = None
        history: list[AlarmHistoryEntry] | None = None
        last_raw = self._last_raw
        report = self._changes.report
        failing = self.stats.failing
        # Only the reads whose result is not the very object they gave last time (found in C: most reads
        # of a tick do not move). Errors are new objects every time, alarm history is never kept.
        for index in compress(batch.indices, map(is_not, results, batch.previous(last_raw))):
            read, result, position = batch.reads[index], results[index], batch.positions[index]
            if isinstance(result, FocasError):
                last_raw[position] = _NOTHING
                self._item_failed(read, result, timestamp, samples)
                continue
            kind = batch.kinds[index]
            if kind is ReadKind.ALARM_HISTORY:
                history = list(result)
                if failing:
                    self._history_answered(read, timestamp, samples)
                continue
            if failing and last_raw[position] is _NOTHING:  # the first answer since a failure (or ever)
                self._answered(pl.drop_key(read.item))
            previous = last_raw[position]
            if result == previous:
                last_raw[position] = result
                continue  # an equal value decoded anew: nothing this read feeds has moved
            last_raw[position] = result
            if kind is ReadKind.ALARM_STATUS:
                alarm_status = int(result)
            elif kind is ReadKind.STATUS:
                status = result
            coercion = batch.elementwise[index]
            if (coercion is not None and type(previous) is list and type(result) is list
                    and len(result) == len(previous)):  # a list that grew offers its new elements in full
                # A list that moved (macros, a PMC range, positions): offer only the elements that moved,
                # each coerced as the extractor would; an equal element was offered last tick and nothing
                # has reported that metric since. Most elements do not move: none is extracted.
                wanted, coerce = coercion
                for spec, new, old in zip(read.metrics, result, previous, strict=False):
                    if new != old or type(new) is not type(old):
                        sample = report(spec.name, new if type(new) is wanted else coerce(new), spec.type, timestamp)
                        if sample is not None:
                            samples.append(sample)
                continue
            values = batch.extractors[index](result)
            # A None value read fine (a vacant macro, an empty position slot): good quality, null value.
            for spec, value in zip(read.metrics, values, strict=False):
                sample = report(spec.name, value, spec.type, timestamp)
                if sample is not None:
                    samples.append(sample)
        if clock_observed or self._clock.news:
            self._clock.samples(timestamp, mid_mono, self._changes.report, samples)
        if status is not None and (moved := self.plant_state.status(status, timestamp)):
            samples.extend(self._changes.filter(moved))
        if alarm_status is not None and self._alarms.status_changed(alarm_status):
            events.extend(await self._read_active_alarms(plan, timestamp, samples))
        fresh = self._history_entries(history) if history else []
        if self._retrying:
            self._answered_again(batch, results, timestamp, samples)
        return TickResult(samples, events, fresh)

    def _retry_dropped(self, now: float) -> None:
        """Put functions dropped `poll.retry_dropped` ago back in the plan (listed as dropped until they answer)."""
        period = self.machine.poll.retry_dropped
        due = [op for op, when in self._dropped.items() if now - when >= period]
        for operation in due:
            del self._dropped[operation]
        self._retry_at = min(self._dropped.values(), default=math.inf) + period
        if not due or self._full_plan is None:
            return
        self._retrying.update(due)
        plan = self._full_plan
        for operation in self._dropped:
            plan = plan.without(operation)
        self._plan = plan
        log.info("retrying dropped functions machine=%s operations=%s", self.machine_id, ",".join(sorted(due)))

    def _answered_again(self, batch: TickBatch, results: Sequence[object], timestamp: int,
                        samples: list[Sample]) -> None:
        """A retried function answered: it is no longer listed in Plan/DroppedFunctions."""
        answered = {read.item.operation for read, result in zip(batch.reads, results, strict=False)
                    if read.item.operation in self._retrying and not isinstance(result, FocasError)}
        if not answered:
            return
        self._retrying -= answered
        log.info("dropped function answers again machine=%s operations=%s", self.machine_id,
                 ",".join(sorted(answered)))
        samples.extend(self._changes.filter([self._dropped_sample(samples, timestamp)]))

    def _probe_before(self, next_due: float) -> float | None:
        """When to read the clock alone, if the tracker wants a reading before the next tick (clock_probe)."""
        half_rtt = self.stats.last_cycle_s / 2
        send_at = self._clock.probes.send_at(time.monotonic(), half_rtt, self._answer_time.usual_s / 2)
        return None if send_at >= self._grid.slot_time(next_due) else send_at

    async def _probe_clock(self, send_at: float) -> None:
        """Read the clock alone at `send_at` (_probe_before). Its time is exact (its own timer, not the shared
        tick grid); its values wait for the next tick, whose stamps it improved."""
        delay = send_at - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)
        wall_before, mono_before = time.time(), time.monotonic()
        (result,) = await self.session.batch(PROBE_ITEMS)
        mono_after, wall_after = time.monotonic(), time.time()
        self.last_progress = mono_after
        self.stats.clock_probes += 1
        self._observe_clock(result, (mono_before + mono_after) / 2, (wall_before + wall_after) / 2,
                            (mono_after - mono_before) / 2)
        self._clock.probes.done(mono_after)
        self._clock.news = True

    def _observe_clock(self, result: object, mid_mono: float, mid_wall: float, half_rtt: float) -> bool:
        """Feed a clock answer to the clock (edge.collect.clock_feed); a failed read counts like any function's."""
        if isinstance(result, FocasError):
            self._count_failure("ReadClock", result)
        elif self.stats.failing and self._clock.is_new_reading(result):
            self._answered("ReadClock")
        return self._clock.observe(result, mid_mono, mid_wall, half_rtt)

    def _count_failure(self, function: str, error: FocasError) -> None:
        """A failed read of `function`: counted, the last error, and failing until it answers again.

        A function the control does not have is not "failing": it is dropped and listed as such.
        """
        self.stats.count_error(function, error)
        self.last_error = f"{function}: {error}"
        if isinstance(error, FunctionNotAvailable | NotSupported):
            self.stats.answered(function)
        elif self.stats.failed(function, error, time.time()):
            log.warning("read failing machine=%s function=%s error=%s", self.machine_id, function, error)

    def _answered(self, function: str) -> None:
        """`function` read fine: if it was failing, say since when and how often."""
        trouble = self.stats.answered(function)
        if trouble is not None:
            log.info("read answers again machine=%s function=%s errors=%d failing_for=%.1fs", self.machine_id,
                     function, trouble.errors, time.time() - trouble.since)

    def _history_answered(self, read: pl.PlannedRead, timestamp: int, samples: list[Sample]) -> None:
        """The history read answered: its metric (no value of its own, BAD while it failed) is GOOD again."""
        function = pl.drop_key(read.item)
        if function not in self.stats.failing:
            return
        self._answered(function)
        for spec in read.metrics:
            sample = self._changes.report(spec.name, None, spec.type, timestamp, Quality.GOOD)
            if sample is not None:
                samples.append(sample)

    def _item_failed(self, read: pl.PlannedRead, error: FocasError, timestamp: int,
                     samples: list[Sample]) -> None:
        self._count_failure(pl.drop_key(read.item), error)
        if isinstance(read.item, it.ReadStatus):
            samples.extend(self._changes.filter(self.plant_state.status_failed(timestamp)))
        if isinstance(error, FunctionNotAvailable | NotSupported) and self._plan is not None:
            operation = pl.drop_key(read.item)
            if operation not in self._dropped:
                self._dropped[operation] = now = time.monotonic()
                self._retry_at = min(self._retry_at, now + self.machine.poll.retry_dropped)
                self._retrying.discard(operation)
                self._plan = self._plan.without(operation)
                again = operation in self._warned_dropped
                self._warned_dropped.add(operation)
                log.log(logging.INFO if again else logging.WARNING,
                        "dropped from plan machine=%s operation=%s error=%s retry_in=%gs", self.machine_id,
                        operation, error, self.machine.poll.retry_dropped)
                samples.extend(self._changes.filter([self._dropped_sample(samples, timestamp)]))
        report = self._changes.report
        for spec in read.metrics:
            sample = report(spec.name, None, spec.type, timestamp, Quality.BAD)
            if sample is not None:
                samples.append(sample)

    def _dropped_sample(self, samples: Sequence[Sample], timestamp: int | None = None) -> Sample:
        when = timestamp if timestamp is not None else (samples[0].timestamp_ms if samples else
                                                        int(time.time() * 1000))
        listed = ",".join(self.dropped)
        return Sample(DROPPED_FUNCTIONS.name, listed, DROPPED_FUNCTIONS.type, when)

    async def _read_active_alarms(self, plan: pl.MachinePlan, timestamp: int,
                                  samples: list[Sample]) -> list[Sample]:
        """The alarm status word changed: read the messages (a second round trip, only on change)."""
        reads = plan.reads_for({pl.Group.ACTIVE_ALARMS})
        if not reads:
            return []
        (result,) = await self.session.batch([reads[0].item])
        if isinstance(result, FocasError):
            self._item_failed(reads[0], result, timestamp, samples)
            return []
        if self.stats.failing:
            self._answered(pl.drop_key(reads[0].item))
        alarms: list[ActiveAlarm] = list(result)
        samples.extend(self._changes.filter(Sample(spec.name, value, spec.type, timestamp)
                                            for spec, value in pl.metric_values(reads[0], alarms)))
        return [Sample(pl.ALARM_EVENT.name, json.dumps(event.as_dict(), separators=(",", ":")),
                       pl.ALARM_EVENT.type, timestamp)
                for event in self._alarms.update(alarms, timestamp)]

    def _history_entries(self, entries: list[AlarmHistoryEntry]) -> list[AlarmHistoryEntry]:
        """Ring entries not yet published, oldest first, with their true occurrence instant.

        The ring holds CNC wall-clock fields (the packed decoder labels them UTC): they are re-read in
        the machine's time zone.
        """
        zone = self.machine.zone
        local = [AlarmHistoryEntry(e.occurred.replace(tzinfo=zone), e.axis_no, e.alm_type, e.alm_no,
                                   e.message) for e in entries]
        return self._history.new_entries(local)

    async def _emit_events(self, events: list[Sample], history: list[AlarmHistoryEntry]) -> None:
        """Publish alarm events; history entries count as published (watermark saved) only after that."""
        history_samples = [Sample(pl.ALARM_HISTORY.name, json.dumps(history_event(e), separators=(",", ":")),
                                  pl.ALARM_HISTORY.type, round(e.occurred.timestamp() * 1000))
                           for e in history]
        await self.sink.device_events(self.machine_id, [*events, *history_samples])
        self._history.commit(history)
