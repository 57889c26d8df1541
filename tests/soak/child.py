"""The daemon under soak, in its own process so its RSS, descriptors and threads are its own.

    python -m tests.soak.child CONFIG KEYS_FILE

Every sample the pollers hand the publisher is appended to KEYS_FILE (one JSON line each: the consumer's
dedup key), written at once so the record costs the daemon no memory. Every few seconds one JSON line of
self-measurements goes to stdout (every SOAK_REPORT_S, default 5). SIGTERM stops the daemon cleanly.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO

from edge.config import load_config
from edge.samples import Sample
from edge.service.blocking_pool import blocking_pool_threads
from edge.service.daemon import Daemon
from edge.service.gc_tuning import CollectorKeeper, tune_collector
from tests.soak.memory_probe import from_environment, heap

REPORT_EVERY_S = float(os.environ.get("SOAK_REPORT_S", "5"))  # bench/outage.py asks for 0.5


def rss_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def spy(daemon: Daemon, out: IO[str]) -> None:
    publisher = daemon.publisher
    data, send_events = publisher.device_data, publisher.device_events

    def record(device_id: str, samples: Sequence[Sample]) -> None:
        for s in samples:
            out.write(json.dumps([device_id, s.name, s.timestamp_ms, s.value], default=str) + "\n")

    async def device_data(device_id: str, samples: Sequence[Sample]) -> None:
        record(device_id, samples)
        await data(device_id, samples)

    async def device_events(device_id: str, events: Sequence[Sample]) -> None:
        record(device_id, events)
        await send_events(device_id, events)

    publisher.device_data = device_data  # type: ignore[method-assign]
    publisher.device_events = device_events  # type: ignore[method-assign]


async def report(daemon: Daemon, started: float) -> None:
    probing = from_environment()
    if probing is not None:
        asyncio.get_running_loop().add_signal_handler(signal.SIGUSR1, probing.probe)
    while True:
        counters = daemon.publisher.counters
        line = {"t": round(time.monotonic() - started, 1), "rss": rss_bytes(),
                "fds": len(os.listdir("/proc/self/fd")), "threads": threading.active_count() - blocking_pool_threads(),
                "pool_threads": blocking_pool_threads(),
                "tasks": len(asyncio.all_tasks()), "spool_rows": counters.get("spool_rows", 0),
                "unconfirmed": counters.get("unconfirmed_batches", 0),
                "suspect_dead": counters.get("suspect_dead", 0), "replayed_rows": counters.get("replayed_rows", 0),
                "replayed_as_samples": counters.get("replayed_rows_as_samples", 0),
                "samples_dropped": counters.get("samples_dropped", 0),
                "online": sum(1 for p in daemon.pollers.values() if p.online), "born": daemon.publisher.ready}
        if probing is not None:
            line.update(heap())
            probing.reports.write(json.dumps({"time": time.time(), **line}) + "\n")
        print(json.dumps(line), flush=True)
        await asyncio.sleep(REPORT_EVERY_S)


async def main(config: Path, keys: Path) -> int:
    with keys.open("a", buffering=1 << 16) as out:
        daemon = Daemon(load_config(config), config)
        # The collector set up as `focas-edge run` has it (edge.service.daemon.run_daemon): without it, a
        # 1,000-machine replay met full collections over the whole fleet's objects, which production never does.
        daemon.collector = CollectorKeeper(lambda: all(p.online for p in daemon.pollers.values()))
        tune_collector()
        spy(daemon, out)
        reporter = asyncio.create_task(report(daemon, time.monotonic()))
        try:
            return await daemon.run()
        finally:
            reporter.cancel()
            out.flush()


def info_logs() -> None:
    """SOAK_LOG_INFO=edge.publish.replay,...: these loggers' INFO lines to stderr (the bench's daemon.log)."""
    for name in filter(None, os.environ.get("SOAK_LOG_INFO", "").split(",")):
        logger = logging.getLogger(name)
        logger.setLevel(logging.INFO)
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(created).3f %(name)s %(message)s"))
        logger.addHandler(handler)


if __name__ == "__main__":
    info_logs()
    sys.exit(asyncio.run(main(Path(sys.argv[1]), Path(sys.argv[2]))))
