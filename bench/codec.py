"""Codec throughput, in process: native frames, 8-byte values, packed ODBALMHIS, Sparkplug DDATA, changes."""

from __future__ import annotations

import math
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta

from bench.report import Check, Result
from bench.timing import Rate, measure_rate
from bench.workload import tick_items
from edge.collect.changes import ChangeDetector
from edge.focas import frame as fr
from edge.focas import packed
from edge.focas.function_entry import Context
from edge.focas.model import AlarmHistoryEntry
from edge.focas.native import item_result, plan_item
from edge.focas.values import decode_scaled_list, encode_scaled_list
from edge.publish.aliases import AliasMap
from edge.publish.node import SparkplugNode
from edge.samples import MetricSpec, MetricType, Quality, Sample
from edge.sim import MachineState, answer_subpacket

SPARKPLUG_TARGET = 1_000_000  # metrics/s
SUBPACKET_TARGET = 100_000  # native response subpackets/s


def _native_exchange() -> tuple[Context, list, list[fr.RequestSubpacket], bytes]:
    """A realistic tick: the plans, their request subpackets and the simulated 30i's answer PDU."""
    state = MachineState("30i")
    ctx = Context.from_sysinfo(state.sysinfo())
    plans = [plan_item(item, ctx) for item in tick_items()]
    requests = [req for plan in plans for req in plan.requests]
    answers = [answer_subpacket(state, req, None, ctx) for req in requests]
    return ctx, plans, requests, fr.encode_response(answers, state.profile.response_version)


def _decode_tick(pdu: bytes, plans: list, ctx: Context) -> list[object]:
    """What the client does with one answer: frame, subpackets, typed value per item."""
    (frame,) = fr.FrameDecoder().feed(pdu)
    answers = fr.decode_response_body(frame.body)
    results: list[object] = []
    offset = 0
    for plan in plans:
        count = len(plan.calls)
        results.append(item_result(plan, answers[offset : offset + count], ctx))
        offset += count
    return results


def _tick_samples(count: int, tick: int) -> list[Sample]:
    """`count` samples shaped like a tick's output: mostly doubles, some strings, ints and booleans."""
    kinds = (MetricType.DOUBLE, MetricType.DOUBLE, MetricType.DOUBLE, MetricType.STRING, MetricType.INT32,
             MetricType.BOOLEAN, MetricType.UINT8, MetricType.DOUBLE)
    samples = []
    for i in range(count):
        kind = kinds[i % len(kinds)]
        value: object = {MetricType.DOUBLE: 100.0 + i + tick * 0.001, MetricType.STRING: f"MEM{tick % 3}",
                         MetricType.INT32: 1234 + tick, MetricType.BOOLEAN: bool(tick % 2),
                         MetricType.UINT8: (i + tick) % 256}[kind]
        samples.append(Sample(f"Metric/{i}", value, kind, 1_700_000_000_000 + tick, Quality.GOOD))
    return samples


def _sparkplug_node(samples: list[Sample]) -> SparkplugNode:
    node = SparkplugNode("bench", "gw", AliasMap(None), clock=lambda: 1_700_000_000_000)
    node.session_started(0)
    node.births()
    node.device_online("m1", [MetricSpec(s.name, s.type) for s in samples], samples)
    return node


def _history(entries: int) -> bytes:
    start = datetime(2024, 5, 1, 8, 0, tzinfo=UTC)
    messages = ("COOLANT LEVEL LOW", "OVER TRAVEL ( +1 )", "DOOR INTERLOCK OPEN", "SOFTTHERMAL (OVC)")
    return packed.encode_alarm_history([
        AlarmHistoryEntry(start + timedelta(minutes=i), i % 4, 15, 1000 + i, messages[i % len(messages)])
        for i in range(entries)])


def run(quick: bool = False, repeats: int = 5) -> Result:
    seconds = 0.1 if quick else 1.0
    repeats = 2 if quick else repeats
    result = Result("codec", "python -m bench codec" + (" --quick" if quick else ""))

    def row(case: str, unit: str, rate: Rate, per_call: str) -> None:
        result.rows.append({"case": case, "unit": unit, "best/s": rate.best, "median/s": rate.median,
                            "worst/s": rate.worst, "per call": per_call})

    ctx, plans, requests, pdu = _native_exchange()
    subpackets = len(requests)
    (frame,) = fr.FrameDecoder().feed(pdu)
    row("native frame decode (FrameDecoder.feed)", "frames", measure_rate(
        lambda: fr.FrameDecoder().feed(pdu), 1, seconds, repeats), f"1 frame, {len(pdu)} B")
    row("native frame build (encode_request)", "frames", measure_rate(
        lambda: fr.encode_request(requests), 1, seconds, repeats), f"{subpackets} subpackets")
    row("native response body split", "subpackets", measure_rate(
        lambda: fr.decode_response_body(frame.body), subpackets, seconds, repeats), f"{subpackets} subpackets")
    decode = measure_rate(lambda: _decode_tick(pdu, plans, ctx), subpackets, seconds, repeats)
    row("native response decode to typed values", "subpackets", decode,
        f"{subpackets} subpackets, {len(plans)} items")
    scaled = encode_scaled_list([None if i % 17 == 0 else i * 0.125 - 40 for i in range(1000)])
    row("8-byte scaled value decode", "values", measure_rate(
        lambda: decode_scaled_list(scaled), 1000, seconds, repeats), "1000 values")
    history = _history(250)
    row("packed ODBALMHIS decode", "entries", measure_rate(
        lambda: packed.decode_alarm_history(history), 250, seconds, repeats), f"250 entries, {len(history)} B")

    encode_rates: list[Rate] = []
    for count in (25, 200):
        batches = [_tick_samples(count, tick) for tick in range(8)]
        node = _sparkplug_node(batches[0])
        turns = iter(range(1 << 62))

        def encode(node: SparkplugNode = node, batches: list[list[Sample]] = batches,
                   turn: Iterator[int] = turns) -> object:
            return node.device_data("m1", batches[next(turn) % 8])

        rate = measure_rate(encode, count, seconds, repeats)
        encode_rates.append(rate)
        row(f"Sparkplug DDATA encode ({count} metrics/message)", "metrics", rate,
            f"{count} metrics -> 1 payload")

    changes = [_tick_samples(100, tick) for tick in range(2)]
    steady = _tick_samples(100, 0)
    detector = ChangeDetector({f"Metric/{i}": 0.5 for i in range(0, 100, 4)})
    flip = iter(range(1 << 62))
    row("change detection, every value changed", "values", measure_rate(
        lambda: detector.filter(changes[next(flip) % 2]), 100, seconds, repeats), "100 samples")
    quiet = ChangeDetector()
    quiet.filter(steady)
    row("change detection, nothing changed", "values", measure_rate(
        lambda: quiet.filter(steady), 100, seconds, repeats), "100 samples")

    result.checks.append(Check("Sparkplug DDATA encode (25 metrics/message, best)", encode_rates[0].best,
                               SPARKPLUG_TARGET, ">=", " metrics/s"))
    result.checks.append(Check("native response decode (best)", decode.best, SUBPACKET_TARGET, ">=",
                               " subpackets/s"))
    result.notes.append("best = the least disturbed of the runs; median/worst show the noise from other load")
    assert math.isfinite(decode.best)
    return result
