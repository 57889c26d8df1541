"""Round trips per poll cycle: K reads against a simulator that waits a fixed time before every answer.

Three clients do the same reads (cnc_statinfo + K-1 single macro reads): our FocasClient batching them
into one request PDU, our FocasClient sending one PDU per item, and the published pyfocas 0.1.1 (one
blocking request per call). The floor is one round trip: a batch of a single item.
"""

from __future__ import annotations

import asyncio
import statistics
import time
from collections.abc import Awaitable, Callable

from bench.procs import SimProcess
from bench.report import Check, Result
from edge.focas import items as it
from edge.focas.client import MAX_SUBPACKETS, FocasClient

LATENCY_S = 0.002
BATCH_TARGET = 1.2
FIRST_MACRO = 500


def cycle_items(k: int) -> tuple[it.ReadItem, ...]:
    """A tuple, as the poller passes a tick's items: the client prepares a repeated tuple's PDUs once."""
    return (it.ReadStatus(), *(it.ReadMacros(FIRST_MACRO + i, FIRST_MACRO + i) for i in range(k - 1)))


async def _ours(port: int, ks: list[int], cycles: int) -> dict[str, dict[int, float]]:
    """Median wall seconds of one cycle, batched and item by item, per K (plus the floor under key 0).

    The floor (one item, one round trip) is measured before and after the series; the middle of those and
    the K = 1 row is kept, so one disturbed measurement does not skew every ratio.
    """
    out: dict[str, dict[int, float]] = {"batched": {}, "per_item": {}}
    async with FocasClient("127.0.0.1", port, timeout=5) as cnc:
        floors = [await _median(lambda: cnc.batch([it.ReadStatus()]), cycles)]
        for k in ks:
            items = cycle_items(k)

            def batched(items: tuple[it.ReadItem, ...] = items) -> Awaitable[object]:
                return cnc.batch(items)

            out["batched"][k] = await _median(batched, cycles)

            async def one_by_one(items: tuple[it.ReadItem, ...] = items) -> None:
                for item in items:
                    await cnc.batch([item])

            out["per_item"][k] = await _median(one_by_one, max(3, cycles // 2))
        floors.append(await _median(lambda: cnc.batch([it.ReadStatus()]), cycles))
        if 1 in out["batched"]:
            floors.append(out["batched"][1])
        out["batched"][0] = statistics.median(floors)
    large = [k for k in ks if k > MAX_SUBPACKETS]
    if large:  # the same reads with max_subpackets raised (a per-machine config key) to hold K in one PDU
        out["one_pdu"] = {}
        async with FocasClient("127.0.0.1", port, timeout=5, max_subpackets=max(large)) as wide:
            for k in large:
                items = cycle_items(k)
                out["one_pdu"][k] = await _median(lambda items=items: wide.batch(items), cycles)  # type: ignore[misc]
    return out


async def _median(call: Callable[[], Awaitable[object]], cycles: int) -> float:
    times = []
    await call()  # warm up
    for _ in range(cycles):
        start = time.perf_counter()
        await call()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _pyfocas(port: int, ks: list[int], cycles: int) -> dict[int, float] | None:
    try:
        from pyfocas.protocol.protocol import FOCAS
    except ImportError:
        return None
    focas = FOCAS("127.0.0.1", port)
    if not focas.connect():
        raise RuntimeError(f"pyfocas could not connect to the simulator on {port}")
    assert focas.socket is not None
    out: dict[int, float] = {}
    try:
        for k in ks:
            def cycle(k: int = k) -> None:
                focas.get_status_info()
                for i in range(k - 1):
                    focas.read_macro(FIRST_MACRO + i)

            cycle()
            times = []
            for _ in range(max(3, cycles // 2)):
                start = time.perf_counter()
                cycle()
                times.append(time.perf_counter() - start)
            out[k] = statistics.median(times)
    finally:
        focas.socket.close()
    return out


def run(quick: bool = False, ks: list[int] | None = None, latency_s: float = LATENCY_S,
        cycles: int | None = None) -> Result:
    ks = ks or ([1, 4, 16] if quick else [1, 4, 8, 16, 30, 64])
    cycles = cycles or (5 if quick else 40)
    command = f"python -m bench roundtrip{' --quick' if quick else ''} --latency {latency_s:g}"
    result = Result("roundtrip", command)
    sim = SimProcess(1, latency=latency_s, fill_macros=f"{FIRST_MACRO}-{FIRST_MACRO + max(ks)}")
    try:
        ours = asyncio.run(_ours(sim.ports[0], ks, cycles))
        theirs = _pyfocas(sim.ports[0], ks, cycles)
    finally:
        sim.stop()
    floor = ours["batched"][0]
    worst_in_one_pdu = 0.0
    for k in ks:
        batched, per_item = ours["batched"][k], ours["per_item"][k]
        pyfocas = theirs.get(k) if theirs else None
        pdus = -(-(k) // MAX_SUBPACKETS)
        one_pdu = ours.get("one_pdu", {}).get(k)
        result.rows.append({
            "K": k, "PDUs": pdus, "batched_ms": batched * 1000, "per_item_ms": per_item * 1000,
            "pyfocas_ms": pyfocas * 1000 if pyfocas else None, "batched/RTT": batched / floor,
            "per_item/RTT": per_item / floor, "pyfocas/RTT": pyfocas / floor if pyfocas else None,
            "per_item/batched": per_item / batched, "pyfocas/batched": pyfocas / batched if pyfocas else None,
            "one_pdu/RTT": one_pdu / floor if one_pdu else None,
        })
        if pdus == 1:
            worst_in_one_pdu = max(worst_in_one_pdu, batched / floor)
        if one_pdu is not None:
            result.checks.append(Check(f"batched cycle / one round trip, K = {k} with max_subpackets: {k}",
                                       one_pdu / floor, BATCH_TARGET, "<="))
    result.checks.append(Check(f"batched cycle / one round trip (K <= {MAX_SUBPACKETS}, worst)", worst_in_one_pdu,
                               BATCH_TARGET, "<="))
    result.notes.append(f"one round trip (floor) = {floor * 1000:.2f} ms with {latency_s * 1000:g} ms simulated "
                        f"latency per request PDU; medians of {cycles} cycles")
    result.notes.append(f"a batch holds at most {MAX_SUBPACKETS} subpackets per PDU (edge.focas.client.MAX_SUBPACKETS);"
                        f" larger K costs ceil(K/{MAX_SUBPACKETS}) round trips unless the machine's max_subpackets"
                        " is raised (one_pdu/RTT: the same reads in one PDU)")
    return result
