"""The command service end to end against an in-memory CNC: every command, whatever it holds, gets exactly
one reply (JSON) and its audit line(s), and nothing is written outside the write policy.

The CNC here is a dict of bytes and macros that records every write call; the publisher records replies.
(tests/integration/test_writes.py drives the same path through a real broker and the simulator.)
"""

from __future__ import annotations

import asyncio
import json
import math
import struct
import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edge.collect import MachinePlan
from edge.command import CommandService
from edge.command.requests import MAX_WRITES_PER_REQUEST
from edge.config import parse_config
from edge.focas import items as it
from edge.focas.model import Capabilities, PmcType
from edge.focas.targets import MacroTarget, PmcTarget, WritableTarget
from edge.publish import CommandSource, DeviceCommands, RefusedMetric
from edge.service.settings import command_settings

CONFIG = """
mqtt: {host: 127.0.0.1, port: 1883, formats: [sparkplug, json], sparkplug: {group_id: plant, edge_node_id: gw}}
state_dir: STATE
writes:
  enabled: true
  rate_limit: {max_writes: 100000, per_s: 60}
  allow:
    - {target: 'macro:500-509', min: -1000, max: 1000}
    - {target: 'pmc:R100-R109', min: 0, max: 100}
    - {target: 'pmc:R110-R119'}
    - {target: 'param:1825', min: 0, max: 5000}
machines:
  - id: m1
    host: 127.0.0.1
    poll: {macros: ['498-511'], pmc: [{range: R98-R104}, {range: R105, data_type: bit}, {range: R106-R111},
           {range: R112-R115, data_type: word}, {range: R116-R119, data_type: float}, {range: R120-R121}]}
"""
ALLOWED_MACROS = range(500, 510)
JSON_SOURCE = CommandSource("json", "focas/m1/cmd")
DCMD_SOURCE = CommandSource("sparkplug", "spBv1.0/plant/DCMD/gw/m1")
UNPACK = {PmcType.BYTE: "B", PmcType.WORD: "h", PmcType.LONG: "i", PmcType.FLOAT: "f", PmcType.DOUBLE: "d"}


class RecordingCnc:
    """Macros and PMC bytes in memory; every write call is kept as (target, value) to check against the policy."""

    def __init__(self) -> None:
        self.macros: dict[int, float] = {}
        self.pmc = bytearray(1000)
        self.writes: list[tuple[WritableTarget, object]] = []
        self.connected = True
        self.sysinfo = None
        self.capabilities = Capabilities("test", frozenset({"write_macro", "write_pmc"}))

    async def read(self, item: it.ReadItem) -> Any:
        return self._read(item)

    async def batch(self, items: Sequence[it.ReadItem]) -> list[Any]:
        return [self._read(item) for item in items]

    def _read(self, item: it.ReadItem) -> Any:
        if isinstance(item, it.ReadMacros):
            return [self.macros.get(n, 0.0) for n in range(item.first, item.last + 1)]
        assert isinstance(item, it.ReadPmc), item
        count = (item.end - item.start + 1) // item.data_type.width
        return list(struct.unpack(f">{count}{UNPACK[item.data_type]}", bytes(self.pmc[item.start:item.end + 1])))

    async def write_macro(self, number: int, value: float) -> None:
        self.writes.append((MacroTarget(number, number), value))
        self.macros[number] = value

    async def write_pmc(self, area: str, start: int, data: bytes) -> None:
        self.writes.append((PmcTarget(area, start, start + len(data) - 1, PmcType.BYTE), data))
        self.pmc[start:start + len(data)] = data

    async def write_pmc_bit(self, area: str, byte: int, bit: int, value: bool) -> None:
        self.writes.append((PmcTarget(area, byte, byte, PmcType.BYTE, bit=bit), value))
        self.pmc[byte] = (self.pmc[byte] & ~(1 << bit)) | (int(value) << bit)


class RecordingPoller:
    def __init__(self) -> None:
        self.session = RecordingCnc()
        self.session_up = asyncio.Event()
        self.session_up.set()
        self.plan: MachinePlan | None = None

    def cnc_time_ms(self) -> int:
        return int(time.time() * 1000)

    async def report(self, samples: Sequence[object]) -> None:
        pass


class RecordingPublisher:
    def __init__(self) -> None:
        self.replies: list[Any] = []

    async def publish_json_reply(self, device_id: str, payload: Any, source: CommandSource) -> None:
        json.dumps(payload, allow_nan=False)  # what the real publisher's strict encoder would refuse
        self.replies.append(payload)


SETTINGS = command_settings(parse_config(CONFIG.replace("STATE", "/nonexistent")))
PLAN = MachinePlan.build(SETTINGS.machines["m1"].poll)


class Harness:
    def __init__(self, state_dir: Path) -> None:
        self.state_dir = state_dir
        self.poller = RecordingPoller()
        self.publisher = RecordingPublisher()
        self.service = CommandService(replace(SETTINGS, state_dir=state_dir), self.publisher,  # type: ignore[arg-type]
                                      {"m1": self.poller})  # type: ignore[dict-item]
        self.poller.plan = self.plan = PLAN

    def audit(self) -> list[dict[str, Any]]:
        path = self.state_dir / "write-audit.jsonl"
        return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []

    def writable_names(self) -> list[str]:
        return [spec.name for read in self.plan.reads for spec in read.metrics if spec.writable]


def run(state_dir: Path, body: Any) -> Harness:
    harness = Harness(state_dir)

    async def main() -> None:
        await body(harness)
        await harness.service.close()

    asyncio.run(main())
    return harness


def inside_policy(target: WritableTarget, value: object) -> bool:
    """The test's own reading of CONFIG's allow-list (not the code under test)."""
    if isinstance(target, MacroTarget):
        return target.first in ALLOWED_MACROS and isinstance(value, float) and -1000 <= value <= 1000
    assert isinstance(target, PmcTarget)
    if target.area != "R" or not 100 <= target.start <= target.end <= 119:
        return False
    if target.end <= 109 and target.bit is None:
        assert isinstance(value, bytes)
        return all(0 <= b <= 100 for b in value)
    return target.start >= 110 or target.bit is not None  # a bit is 0 or 1: inside 0..100


# ---- the 400-digit integer: OverflowError, no reply, no audit line on main -----------------------------


@pytest.mark.parametrize("target", ["macro:500", "pmc:R116.float", "pmc:R116-R123.double", "param:1825/1"])
def test_a_400_digit_integer_is_answered_and_audited_as_wrong_type(tmp_path: Path, target: str) -> None:
    async def body(h: Harness) -> None:
        await h.service.on_json_command("m1", json.dumps({"id": "big", "target": target, "value": 10**400}).encode(),
                                        JSON_SOURCE)

    h = run(tmp_path, body)
    (answer,) = h.publisher.replies
    assert answer["id"] == "big" and answer["error"]["code"] == "wrong_type", answer
    assert "401 digits is larger than any number a CNC holds" in answer["error"]["message"]
    (line,) = h.audit()
    assert line["request_id"] == "big" and line["outcome"] == "wrong_type"
    assert h.poller.session.writes == []


def test_nan_infinity_and_wrong_types_are_answered_and_the_audit_stays_strict_json(tmp_path: Path) -> None:
    requests = [b'{"id": 1, "target": "macro:500", "value": NaN}',
                b'{"id": 2, "target": "pmc:R116.float", "value": -Infinity}',
                b'{"id": 3, "target": "pmc:R100", "value": {"a": [1, 2]}}',
                b'{"id": 4, "target": "pmc:R100-R101", "value": [1, NaN]}',
                b'{"id": 5, "target": 7, "value": 1}',
                b'{"id": 6, "target": "macro:500", "value": 1e999}']

    async def body(h: Harness) -> None:
        for payload in requests:
            await h.service.on_json_command("m1", payload, JSON_SOURCE)

    h = run(tmp_path, body)
    assert [r["id"] for r in h.publisher.replies] == [1, 2, 3, 4, 5, 6]
    assert all(r["ok"] is False for r in h.publisher.replies)
    text = (tmp_path / "write-audit.jsonl").read_text()
    assert "NaN" not in text.replace('"nan"', "") and len(text.splitlines()) == 6
    for line in text.splitlines():
        json.loads(line, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c} in the audit"))
    assert h.poller.session.writes == []


def test_a_list_over_the_limit_answers_every_id_and_audits_one_line(tmp_path: Path) -> None:
    request = [{"id": f"w{n}", "target": "macro:500", "value": n} for n in range(MAX_WRITES_PER_REQUEST + 1)]
    h = _run_large(tmp_path, request)
    (answer,) = h.publisher.replies
    assert [r["id"] for r in answer] == [f"w{n}" for n in range(MAX_WRITES_PER_REQUEST + 1)]
    assert {r["error"]["code"] for r in answer} == {"malformed"}
    assert "65 writes in one request; at most 64" in answer[0]["error"]["message"]
    (line,) = h.audit()
    assert line["outcome"] == "malformed" and line["request_id"][:2] == ["w0", "w1"]
    assert h.poller.session.writes == []


def _run_large(tmp_path: Path, request: object) -> Harness:
    """The request above is ~3.5 kB: raise the byte cap so the count cap is what refuses it."""
    async def body(h: Harness) -> None:
        h.service.settings = _with_payload(h, 65536)
        await h.service.on_json_command("m1", json.dumps(request).encode(), JSON_SOURCE)

    return run(tmp_path, body)


def _with_payload(h: Harness, max_bytes: int) -> Any:
    return replace(h.service.settings, max_payload_bytes=max_bytes)


# ---- DCMD: capped like JSON, one audit line when refused ------------------------------------------------


def test_a_dcmd_of_5000_unknown_metrics_is_one_audit_line(tmp_path: Path) -> None:
    refused = tuple(RefusedMetric(f"Unknown/Metric{n:04d}", "unknown_metric", f"DCMD m1: metric Unknown/Metric{n:04d} "
                                  "not in its DBIRTH") for n in range(5000))

    async def body(h: Harness) -> None:
        await h.service.on_device_commands(DeviceCommands("m1", (), refused, 580_000), DCMD_SOURCE)

    h = run(tmp_path, body)
    (line,) = h.audit()
    assert line["outcome"] == "payload_too_large" and "580000 bytes" in line["message"]
    assert "5000 writes in this command" in line["message"]
    assert len(json.dumps(line)) < 2000
    assert h.service.counters["writes_refused"] == 5000


def test_a_dcmd_over_64_metrics_is_refused_whole(tmp_path: Path) -> None:
    async def body(h: Harness) -> None:
        writes = tuple((f"PMC/R{100 + n % 20}", 1) for n in range(65))
        await h.service.on_device_commands(DeviceCommands("m1", writes, (), 2000), DCMD_SOURCE)

    h = run(tmp_path, body)
    (line,) = h.audit()
    assert line["outcome"] == "malformed" and "65 metrics in one DCMD; at most 64" in line["message"]
    assert h.poller.session.writes == []


def test_a_dcmd_with_one_refused_metric_writes_nothing_and_is_one_line(tmp_path: Path) -> None:
    async def body(h: Harness) -> None:
        commands = DeviceCommands("m1", (("Macro/500", 1.5), ("PMC/R110", 7)),
                                  (RefusedMetric("Status/Run", "invalid_target", "read-only"),), 60)
        await h.service.on_device_commands(commands, DCMD_SOURCE)

    h = run(tmp_path, body)
    (line,) = h.audit()
    assert line["outcome"] == "invalid_target" and line["target"] == "Status/Run"
    assert "3 writes in this command, none sent" in line["message"]
    assert h.poller.session.writes == []


def test_a_good_dcmd_is_written_and_audited_per_write(tmp_path: Path) -> None:
    async def body(h: Harness) -> None:
        commands = DeviceCommands("m1", (("Macro/500", 1.5), ("PMC/R110", 7), ("PMC/R111", 8)), (), 60)
        await h.service.on_device_commands(commands, DCMD_SOURCE)

    h = run(tmp_path, body)
    assert [(a["target"], a["outcome"]) for a in h.audit()] == [("macro:500", "ok"), ("pmc:R110-R111", "ok")]
    assert len(h.poller.session.writes) == 2


# ---- the property: any command -> one reply, its audit lines, nothing outside the policy -----------------

ids = st.one_of(st.none(), st.text(max_size=6), st.integers(), st.just(10**400), st.floats(), st.booleans())
numbers = st.one_of(st.integers(-300, 300), st.integers(), st.just(10**400), st.just(-(10**400)), st.floats(),
                    st.just(math.nan), st.just(math.inf))
values = st.one_of(numbers, st.booleans(), st.none(), st.text(max_size=4), st.lists(numbers, max_size=9),
                   st.dictionaries(st.text(max_size=3), numbers, max_size=2))
targets = st.one_of(st.sampled_from([
    "macro:500", "macro:509", "macro:510", "macro:0", "macro:50", "macro:500-501", "pmc:R100", "pmc:R109",
    "pmc:R100-R103", "pmc:R105.3", "pmc:R99", "pmc:R110", "pmc:R110-R119", "pmc:R112.word", "pmc:R114-R117.long",
    "pmc:R116.float", "pmc:R112-R119.double", "pmc:R120", "pmc:D100", "param:1825/1", "param:1825",
    "param:1815/1.3", "diag:300", "macro:500@2", "pmc:R100.9", ""]), st.text(max_size=10), st.integers())
write = st.fixed_dictionaries({"target": targets, "value": values},
                              optional={"id": ids, "client": st.text(max_size=5), "path": st.integers(-1, 3),
                                        "extra": st.just(1)})
documents = st.one_of(write, st.lists(write, min_size=0, max_size=8),
                      st.lists(write, min_size=MAX_WRITES_PER_REQUEST + 1, max_size=MAX_WRITES_PER_REQUEST + 3),
                      values)
SLOW = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                         HealthCheck.data_too_large])


@SLOW
@given(st.lists(documents, min_size=1, max_size=4), st.sampled_from([4096, 65536]))
def test_property_every_json_command_one_reply_its_audit_and_nothing_outside_the_policy(
        commands: list[object], max_bytes: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        lines_per_command: list[int] = []

        async def body(h: Harness) -> None:
            h.service.settings = _with_payload(h, max_bytes)
            for document in commands:
                before = len(h.audit())
                await h.service.on_json_command("m1", json.dumps(document).encode(), JSON_SOURCE)
                lines_per_command.append(len(h.audit()) - before)

        h = run(Path(tmp), body)
        assert len(h.publisher.replies) == len(commands), "exactly one reply per command"
        for document, answer, lines in zip(commands, h.publisher.replies, lines_per_command, strict=True):
            answered = answer if isinstance(answer, list) else [answer]
            readable = len(json.dumps(document).encode()) <= max_bytes
            if isinstance(document, list) and document and readable:
                assert isinstance(answer, list), answer  # a list is answered per element, even over the limit
                assert len(answer) == len(document)  # every element answered, in order
                sent = [d.get("id") if isinstance(d, dict) and isinstance(d.get("id"), str | int) else None
                        for d in document]
                assert [r["id"] for r in answer] == sent
                whole = len(document) > MAX_WRITES_PER_REQUEST
                assert lines == (1 if whole else len(document)), (lines, len(document))
            else:
                assert lines == 1
            assert all(r["ok"] or r["error"]["code"] for r in answered)
        for target, value in h.poller.session.writes:
            assert inside_policy(target, value), (target, value)


dcmd_values = st.one_of(st.floats(), st.integers(-(2**63), 2**64), st.booleans(), st.text(max_size=3), st.none())
refusals = st.builds(RefusedMetric, st.one_of(st.none(), st.text(max_size=8)),
                     st.sampled_from(["unknown_metric", "wrong_type", "invalid_target", "malformed", "bogus"]),
                     st.text(max_size=20))


@SLOW
@given(st.data())
def test_property_every_dcmd_audited_once_when_refused_and_nothing_outside_the_policy(data: st.DataObject) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        harness = Harness(Path(tmp))
        names = st.one_of(st.sampled_from(harness.writable_names()), st.text(max_size=10))
        count = data.draw(st.sampled_from([3, 8, MAX_WRITES_PER_REQUEST + 1]))
        writes = data.draw(st.lists(st.tuples(names, dcmd_values), max_size=count))
        refused = data.draw(st.lists(refusals, max_size=2))
        size = data.draw(st.sampled_from([40, 4096, 5000, 580_000]))
        commands = DeviceCommands("m1", tuple(writes), tuple(refused), size)

        async def body(h: Harness) -> None:
            await h.service.on_device_commands(commands, DCMD_SOURCE)

        h = run(Path(tmp), body)
        lines = h.audit()
        cnc = h.poller.session.writes
        assert lines, "every DCMD leaves an audit line"
        if not cnc:
            assert len(lines) == 1, "a DCMD refused is one audit line"
        else:
            assert not refused and size <= 4096 and len(writes) <= MAX_WRITES_PER_REQUEST
            assert len(lines) <= len(writes)
        for target, value in cnc:
            assert inside_policy(target, value), (target, value)
