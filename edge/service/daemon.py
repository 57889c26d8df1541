"""The collector daemon: one publisher, one poller per machine, signals, reload and the watchdog.

SIGTERM/SIGINT: stop polling, DDEATH every machine, NDEATH, DISCONNECT, close PDUs to the CNCs, exit 0.
SIGHUP: reload the config without dropping the broker session; machines added, removed or changed get
their DBIRTH/DDEATH (in a fleet file with `gateways:`, a machine moved to another gateway is one removed).
The systemd watchdog is pinged only while every poll loop makes progress.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import platform
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from edge import ConfigError, __version__
from edge.collect import MachinePoller, MachineSettings, SessionFactory, StartGate, TickGrid, default_session
from edge.command import CommandService
from edge.config import GATEWAY_ENV, Config, MachineConfig, listen_port, load_config
from edge.config.listen_port import bind_problem
from edge.config.service_access import current_account, owner_of, state_dir_problem, state_files_problem
from edge.publish import Publisher, open_spool
from edge.samples import MetricType, Sample
from edge.service import heap_trim
from edge.service.blocking_pool import install_blocking_pool
from edge.service.fd_limit import ensure_fd_limit, fds_needed
from edge.service.gc_tuning import CollectorKeeper, tune_collector
from edge.service.opcua_output import opcua_output
from edge.service.outputs import Outputs
from edge.service.sdnotify import SystemdNotifier
from edge.service.settings import command_settings, machine_settings, opcua_settings, publish_settings
from edge.service.state_lock import StateDirLock
from edge.service.status_gateway import systemd_status
from edge.service.trend_store import close_trends, keep_saved, open_trends

if TYPE_CHECKING:
    from edge.service.status_http import StatusServer

log = logging.getLogger(__name__)

NODE_METRICS_PERIOD_S = 5.0
# Machines started per second at start-up: each start (connect, static reads, plan, DBIRTH) costs the loop
# milliseconds, and 1,000 of them in the same second kept answers waiting past the request timeout.
STARTS_PER_S = 200.0
# Machines between their CNC session's connect and their DBIRTH at a time (edge.collect.start_gate): bounds
# the start-up work in front of every answer, so the request deadlines measure the CNC, not the loop.
START_SLOTS = 64
SYSTEMD_STATUS_PERIOD_S = 1.0


class Daemon:
    def __init__(self, config: Config, config_path: Path | None = None,
                 session_factory: SessionFactory = default_session,
                 notifier: SystemdNotifier | None = None) -> None:
        self.config = config
        self.config_path = config_path
        self.session_factory = session_factory
        self.notifier = notifier or SystemdNotifier()
        self.state_dir = config.resolved_state_dir
        self._source = str(config_path) if config_path is not None else "config"
        settings = publish_settings(config)  # the password first: a missing one refuses before state_dir
        self.lock = self._take_state_dir()
        try:
            self.spool = open_spool(self.state_dir, int(config.spool.max_bytes), config.spool.max_age_s)
        except BaseException:
            self.lock.release()
            raise
        self.publisher = Publisher(settings, spool=self.spool)
        # A replay of a 1,000-machine outage leaves ~16-18 MB of freed C heap that glibc keeps (docs/
        # performance.md, "Broker outage at 1,000 machines: the RSS step"): given back once the spool is empty.
        self.publisher.after_replay = heap_trim.trim
        self.pollers: dict[str, MachinePoller] = {}
        self.tick_grid = TickGrid(config.poll_grid_step_s)  # machines due in the same slot share one loop turn
        self.start_gate = StartGate(START_SLOTS)
        self.commands = CommandService(command_settings(config), self.publisher, self.pollers)
        self.opcua = opcua_output(opcua_settings(config), self.commands)  # None unless opcua.enabled
        # What the plant page draws; the page is its only reader, and `http` takes effect at a restart only:
        # with the page off, nothing records or saves it (a saved day stays on disk for the next run with it).
        self.trends = open_trends(self.state_dir, (m.id for m in config.devices())) if config.http.enabled else None
        self.outputs = Outputs(self.publisher, [o for o in (self.trends, self.opcua) if o is not None])
        self.publisher.on_device_command = self.commands.on_device_commands
        self.publisher.on_json_command = self.commands.on_json_command
        self.publisher.node_metrics_source = self.node_metrics
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._stop = asyncio.Event()
        self._reload_requested = asyncio.Event()
        self._started = time.monotonic()
        self.status_http: StatusServer | None = None
        # run_daemon sets it (the process is the daemon's alone): freezes the machines' objects once born
        self.collector: CollectorKeeper | None = None

    def _take_state_dir(self) -> StateDirLock:
        """One daemon per state_dir, and only one whose user can read and write every file in it.

        Both refusals are ConfigErrors (one line, exit 2, not restarted by the unit): restarting cannot
        help until someone stops the other daemon or runs the chown the line gives.
        """
        account = current_account()
        try:
            lock = StateDirLock.acquire(self.state_dir)
        except ConfigError as exc:
            raise ConfigError(exc.problems, self._source) from None
        except PermissionError as exc:  # a lock file left by a run as another user
            problem = state_files_problem(account, self.state_dir)
            raise ConfigError([problem or f"state_dir: cannot open {exc.filename} ({exc.strerror})"],
                              self._source) from None
        problem = state_files_problem(account, self.state_dir)
        if problem is not None:
            lock.release()
            raise ConfigError([problem], self._source)
        info = self.state_dir.stat()
        if account.uid == 0 and info.st_uid != 0:
            owner = owner_of(info)
            log.warning("running as root in state_dir=%s, which belongs to %s: the files this run creates there "
                        "will be root's and the service will refuse them; afterwards: chown -R %s %s",
                        self.state_dir, owner, owner, self.state_dir)
        return lock

    # ---- lifecycle -----------------------------------------------------------------------------------
    async def run(self) -> int:
        install_blocking_pool(asyncio.get_running_loop())
        self._install_signals()
        try:
            await self._start_status_http()
            self._check_opcua_port()
        except BaseException:
            self.spool.close()
            self.lock.release()
            raise
        self.publisher.set_node_metrics(self.node_metrics())
        await self.publisher.start()
        await self._start_opcua()
        devices = self.config.devices()
        spread = max(1.0, len(devices) / STARTS_PER_S)  # a fleet's first connects spread, not in one burst
        for machine in devices:
            self._start_machine(machine, spread)
        if self.collector is not None:
            self.collector.machines_started()
        self.notifier.ready(f"polling {len(self.pollers)} machine(s)")
        log.info("started version=%s machines=%d state_dir=%s", __version__, len(self.pollers), self.state_dir)
        background = [asyncio.create_task(self._node_metrics_loop(), name="node-metrics")]
        if self.trends is not None:
            background.append(asyncio.create_task(keep_saved(self.trends, self.state_dir), name="plant-timelines"))
        if self.notifier.enabled:
            background.append(asyncio.create_task(self._systemd_status_loop(), name="systemd-status"))
        interval = self.notifier.watchdog_interval()
        if interval:
            background.append(asyncio.create_task(self._watchdog_loop(interval), name="watchdog"))
        if self.collector is not None:
            background.append(asyncio.create_task(self.collector.run(), name="collector-keeper"))
        try:
            while not self._stop.is_set():
                reload_wait = asyncio.create_task(self._reload_requested.wait())
                stop_wait = asyncio.create_task(self._stop.wait())
                await asyncio.wait({reload_wait, stop_wait}, return_when=asyncio.FIRST_COMPLETED)
                reload_wait.cancel()
                stop_wait.cancel()
                if self._reload_requested.is_set() and not self._stop.is_set():
                    self._reload_requested.clear()
                    await self.reload()
        finally:
            self.notifier.stopping()
            await cancel_and_wait(background)
            await self.shutdown()
        return 0

    def request_stop(self) -> None:
        self._stop.set()

    def request_reload(self) -> None:
        self._reload_requested.set()

    async def shutdown(self) -> None:
        """Stop polling, DDEATHs + NDEATH + DISCONNECT, then close PDUs to every CNC."""
        await self.commands.close()
        await cancel_and_wait(list(self._tasks.values()))
        with contextlib.suppress(Exception):
            await self.publisher.stop()
        self.spool.close()  # after the publisher spooled what it could not confirm
        await asyncio.gather(*(p.close() for p in self.pollers.values()), return_exceptions=True)
        self._tasks.clear()
        if self.opcua is not None:
            await self.opcua.stop()
        if self.status_http is not None:
            await self.status_http.stop()
            self.status_http = None
        if self.trends is not None:
            close_trends(self.trends, self.state_dir)
        self.lock.release()  # last: nothing of this daemon touches state_dir any more
        log.info("stopped")

    async def _start_status_http(self) -> None:
        """The optional /healthz + /metrics endpoint (config `http`, off by default)."""
        http = self.config.http
        if not http.enabled or self.status_http is not None:
            return
        # Imported here: the endpoint is off by default, and it brings prometheus-client, http.server and the
        # plant page (1.3 MB of the daemon's resident memory) that a daemon without it never needs.
        from edge.service.status_http import StatusServer

        server = StatusServer(self, http.host, http.port, http.healthy_share)
        try:
            await server.start()
        except OSError as exc:  # the port taken, a host not on this machine: a setting, not a crash
            raise ConfigError([bind_problem(http.host, http.port, exc)], self._source) from None
        self.status_http = server

    def _check_opcua_port(self) -> None:
        """The OPC UA port taken is refused like the status port's (one line, exit 2), before anything starts:
        asyncua would log a traceback and the daemon would run without the server nobody asked to lose."""
        if self.opcua is None:
            return
        settings = self.opcua.settings
        problem = listen_port.probe(settings.host, settings.port, "opcua")
        if problem is not None:
            raise ConfigError([problem], self._source)

    async def _start_opcua(self) -> None:
        """The optional OPC UA server; one that cannot start for another reason than its port (an unreadable
        certificate, say) is an error logged, and the daemon goes on polling and publishing without it."""
        if self.opcua is None:
            return
        try:
            await self.opcua.start()
        except Exception as exc:
            log.error("OPC UA server not started, running without it endpoint=%s error=%r",
                      self.opcua.settings.endpoint, exc)
            self.outputs.others.remove(self.opcua)
            self.opcua = None

    def _install_signals(self) -> None:
        loop = asyncio.get_running_loop()
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(signal.SIGTERM, self.request_stop)
            loop.add_signal_handler(signal.SIGINT, self.request_stop)
            loop.add_signal_handler(signal.SIGHUP, self.request_reload)

    # ---- machines ------------------------------------------------------------------------------------
    def _start_machine(self, machine: MachineConfig, spread_s: float = 1.0) -> None:
        poller = MachinePoller(machine_settings(self.config, machine), self.outputs, self.state_dir,
                               self.session_factory, jitter_s=spread_s, grid=self.tick_grid,
                               start_gate=self.start_gate)
        self.pollers[machine.id] = poller
        task = asyncio.create_task(poller.run(), name=f"poll-{machine.id}")
        task.add_done_callback(self._poller_done)
        self._tasks[machine.id] = task

    def _poller_done(self, task: asyncio.Task[None]) -> None:
        if task.cancelled():
            return
        error = task.exception()
        if error is not None:
            log.error("poll loop ended task=%s error=%r", task.get_name(), error)

    async def _stop_machine(self, machine_id: str) -> None:
        task = self._tasks.pop(machine_id, None)
        poller = self.pollers.pop(machine_id, None)
        if task is not None:
            await cancel_and_wait([task])
        if poller is not None:
            if poller.online:
                with contextlib.suppress(Exception):
                    await self.outputs.device_offline(machine_id)
            await poller.close()

    async def reload(self) -> None:
        """Apply a changed config file without dropping the broker session."""
        if self.config_path is None:
            return
        self.notifier.reloading()
        try:  # in a thread: parsing 1,000 machines takes seconds, and the poll loops must keep ticking meanwhile
            new = await asyncio.to_thread(load_config, self.config_path, gateway=self.config.gateway)
        except ConfigError as exc:
            log.error("reload refused, keeping the running config: %s", exc)
            self.notifier.ready("reload refused: bad config")
            return
        if new.mqtt != self.config.mqtt:
            log.warning("reload: mqtt settings changed; they take effect at the next restart")
        if new.http != self.config.http:
            log.warning("reload: http settings changed; they take effect at the next restart")
        if new.opcua != self.config.opcua:
            log.warning("reload: opcua settings changed; they take effect at the next restart")
        step = new.poll_grid_step_s
        if step != self.tick_grid.step_s:
            log.info("reload: poll grid %gs -> %gs", self.tick_grid.step_s, step)
            self.tick_grid.step_s = step  # before any new machine sleeps on it
        old = {m.id: m for m in self.config.devices()}
        fresh = {m.id: m for m in new.devices()}
        changed = [i for i in old if i in fresh and (old[i] != fresh[i] or
                                                     self.config.alarms_for(old[i]) != new.alarms_for(fresh[i]))]
        removed = [i for i in old if i not in fresh]
        added = [i for i in fresh if i not in old]
        owners = {machine: gateway for gateway, machines in new.fleet.items() for machine in machines}
        for machine_id in removed:
            if machine_id in owners:
                log.info("reload: machine %s moved to gateway %s", machine_id, owners[machine_id])
        self.config = new
        self.commands.reconfigure(command_settings(new))
        for machine_id in removed + changed:
            await self._stop_machine(machine_id)
        for machine_id in removed:
            if self.trends is not None:
                self.trends.forget(machine_id)
        for machine_id in changed + added:
            self._start_machine(fresh[machine_id])
        if self.collector is not None and (changed or added):
            self.collector.machines_started()
        log.info("reloaded added=%s removed=%s changed=%s", added, removed, changed)
        self.notifier.ready(f"polling {len(self.pollers)} machine(s)")

    # ---- health --------------------------------------------------------------------------------------
    def healthy(self, stale_after_s: float | None = None) -> bool:
        """Every poll loop alive and making progress (ticks, or connect attempts while a CNC is away)."""
        now = time.monotonic()
        for machine_id, task in self._tasks.items():
            if task.done():
                return False
            poller = self.pollers[machine_id]
            limit = stale_after_s or _stale_limit(poller.machine)
            if now - poller.last_progress > limit:
                return False
        return True

    async def _watchdog_loop(self, interval: float) -> None:
        while True:
            if self.healthy():
                self.notifier.watchdog()
            else:
                log.error("watchdog withheld: a poll loop is not making progress")
            await asyncio.sleep(interval)

    def node_metrics(self) -> list[Sample]:
        now = int(time.time() * 1000)
        connected = sum(1 for p in self.pollers.values() if p.online)
        overruns = sum(p.stats.overruns for p in self.pollers.values())
        counters = self.publisher.counters
        published = int(sum(v for k, v in counters.items() if k.startswith("published")))
        values: list[tuple[str, object, MetricType]] = [
            ("Properties/Software Version", __version__, MetricType.STRING),
            ("Properties/OS", f"{platform.system()} {platform.machine()}", MetricType.STRING),
            ("Gateway/Machines", len(self.pollers), MetricType.INT32),
            ("Gateway/MachinesConnected", connected, MetricType.INT32),
            ("Gateway/PollOverruns", overruns, MetricType.INT64),
            ("Gateway/MessagesPublished", published, MetricType.INT64),
            ("Gateway/UptimeSeconds", int(time.monotonic() - self._started), MetricType.INT64),
        ]
        values += [("Spool/Depth", self.spool.pending(), MetricType.INT64),
                   ("Spool/Dropped", self.spool.dropped, MetricType.INT64)]
        writes = self.commands.counters
        values += [(f"Writes/{name}", int(writes.get(key, 0)), MetricType.INT64)
                   for name, key in (("Ok", "writes_ok"), ("Failed", "writes_failed"), ("Refused", "writes_refused"))]
        return [Sample(name, value, kind, now) for name, value, kind in values]

    @property
    def uptime_s(self) -> float:
        return time.monotonic() - self._started

    async def _systemd_status_loop(self) -> None:
        """`systemctl status` shows machines connected and the broker session (down since, last error)."""
        shown = ""
        while True:
            await asyncio.sleep(SYSTEMD_STATUS_PERIOD_S)
            line = systemd_status(self)
            if line != shown:
                shown = line
                self.notifier.status(line)

    async def _node_metrics_loop(self) -> None:
        while True:
            await asyncio.sleep(NODE_METRICS_PERIOD_S)
            self.publisher.set_node_metrics(self.node_metrics())


async def cancel_and_wait(tasks: list[asyncio.Task[None]]) -> None:
    """Cancel tasks and wait until every one has ended.

    A cancellation can be lost (Python 3.11's asyncio.wait_for swallows one that arrives as its inner
    call completes, in library code too), so a task still running a second later is cancelled again.
    """
    pending = {task for task in tasks if not task.done()}
    for task in pending:
        task.cancel()
    while pending:
        _, pending = await asyncio.wait(pending, timeout=1.0)
        for task in pending:
            log.warning("task still running after cancel, cancelling again task=%s", task.get_name())
            task.cancel()


def _stale_limit(machine: MachineSettings) -> float:
    timeouts = machine.timeouts
    periods = machine.poll.periods
    return 3 * (timeouts.request_s + timeouts.connect_s + timeouts.backoff_max_s) + max(
        periods.status, periods.macros, periods.pmc)


def run_daemon(config_path: Path, configure: Callable[[Daemon], None] | None = None,
               gateway: str | None = None) -> int:
    """`gateway`: which gateway of a fleet file with `gateways:` this process is (kept across reloads)."""
    config = load_config(config_path, gateway=gateway)
    if config.fleet and gateway is None:  # without a name, load_config answers with an overview, not a box
        raise ConfigError([f"the file lists gateways ({', '.join(config.fleet)}): say which one this is with "
                           f"--gateway NAME or {GATEWAY_ENV}=NAME"], str(config_path))
    for warning in config.warnings:
        log.warning("config: %s", warning)
    unusable = state_dir_problem(config.resolved_state_dir)
    if unusable is not None:
        raise ConfigError([unusable], str(config_path))
    devices = config.devices()
    ensure_fd_limit(fds_needed(len(devices), sum(1 for d in devices if d.fwlib_host)))

    async def main() -> int:
        daemon = Daemon(config, config_path)
        daemon.collector = CollectorKeeper(lambda: all(p.online for p in daemon.pollers.values()))
        if configure is not None:
            configure(daemon)
        tune_collector()
        return await daemon.run()

    return asyncio.run(main())
