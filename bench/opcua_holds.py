"""Which OPC UA requests hold the daemon's loop, and how long: `python -m bench.opcua_holds CONFIG OUT.json`.

bench.latency_daemon's probes, plus every step of asyncua's request handling timed: a request's coroutine is
driven step by step (each `send` into it is one hold of the loop, until its next real suspension), so the
longest hold per request type is what the poll loop waited at worst behind that request. Publishes (the
subscription's `publish_results`: notifications encoded and sent) are timed the same way. SIGUSR2 writes the
window's figures with the holds since the daemon started under "holds" (they are not reset with the window:
`bench opcua --diagnose` reads them once more after the burst, the subscription and the burst included).
"""

from __future__ import annotations

import json
import signal
import sys
import time
from collections.abc import Callable, Coroutine, Generator
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.server.internal_subscription import InternalSubscription
from asyncua.server.uaprocessor import UaProcessor

from bench.latency_daemon import Window, install
from edge.service.daemon import Daemon, run_daemon

# request type -> each hold of the loop (a step of its coroutine): (wall, the loop thread's CPU) seconds. The
# CPU time is the request's own cost: on a shared host the wall time includes other processes' turns
HOLDS: dict[str, list[tuple[float, float]]] = {}


class _Stepped:
    """An awaitable driving `coro` one step at a time, each step's duration added to HOLDS[key]."""

    def __init__(self, coro: Coroutine[Any, Any, Any], key: str) -> None:
        self._coro, self._key = coro, key

    def __await__(self) -> Generator[Any, Any, Any]:
        it = self._coro.__await__()
        holds = HOLDS.setdefault(self._key, [])
        value: Any = None
        error: BaseException | None = None
        wall, cpu = time.perf_counter, time.thread_time
        while True:
            started, ran = wall(), cpu()
            try:
                yielded = it.throw(error) if error is not None else it.send(value)
            except StopIteration as stop:
                holds.append((wall() - started, cpu() - ran))
                return stop.value
            holds.append((wall() - started, cpu() - ran))
            try:
                value, error = (yield yielded), None
            except BaseException as exc:
                value, error = None, exc


_NAMES = {ua.ObjectIds.__dict__[name]: name.removesuffix("Request_Encoding_DefaultBinary")
          for name in dir(ua.ObjectIds) if name.endswith("Request_Encoding_DefaultBinary")}


def watch_asyncua() -> None:
    """Time every request's and every publish's steps (HOLDS)."""
    process: Callable[..., Any] = UaProcessor._process_message

    async def timed_process(self: Any, typeid: ua.NodeId, requesthdr: Any, seqhdr: Any, body: Any) -> Any:
        key = _NAMES.get(typeid.Identifier, str(typeid.Identifier))
        return await _Stepped(process(self, typeid, requesthdr, seqhdr, body), key)

    UaProcessor._process_message = timed_process  # type: ignore[method-assign]
    publish: Callable[..., Any] = InternalSubscription.publish_results

    async def timed_publish(self: Any, requestdata: Any = None) -> Any:
        return await _Stepped(publish(self, requestdata), "(publish)")

    InternalSubscription.publish_results = timed_publish  # type: ignore[method-assign]


def summary() -> dict[str, dict[str, Any]]:
    """Per request type, longest first: how many steps, the 5 longest by CPU and by wall time, the CPU total (ms)."""
    out = {}
    for key, holds in sorted(HOLDS.items(), key=lambda kv: -max((c for _, c in kv[1]), default=0)):
        by_cpu = sorted((c for _, c in holds), reverse=True)
        by_wall = sorted((w for w, _ in holds), reverse=True)
        out[key] = {"steps": len(holds), "top5_cpu_ms": [round(h * 1000, 1) for h in by_cpu[:5]],
                    "top5_wall_ms": [round(h * 1000, 1) for h in by_wall[:5]], "cpu_ms": sum(by_cpu) * 1000}
    return out


def main() -> int:
    config, out = Path(sys.argv[1]), Path(sys.argv[2])
    window = Window(spread_clocks="--spread-clocks" in sys.argv[3:])
    signal.signal(signal.SIGUSR1, lambda signum, frame: window.reset())
    signal.signal(signal.SIGUSR2, lambda signum, frame: out.write_text(
        json.dumps({**window.report(), "holds": summary()}, indent=1)))
    watch_asyncua()

    def configure(daemon: Daemon) -> None:
        install(window, daemon)

    return run_daemon(config, configure)


if __name__ == "__main__":
    sys.exit(main())
