"""Remote writes end to end: MQTT client -> real mosquitto -> the daemon -> simulated CNC over TCP.

Every write is checked three ways: the reply (JSON) or the published read-back (DCMD), the simulator's
write log (what really reached the CNC, and how often), and the published data.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from edge.config import parse_config
from edge.publish.sparkplug_b_pb2 import DataType, Payload
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, Machine, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

TIMEOUTS = "timeouts: {request_s: 0.5, connect_s: 0.5, backoff_initial_s: 0.05, backoff_max_s: 0.2}"
POLL = ("poll: {periods: {status: 0.25, macros: 0.5, pmc: 0.5, params: 0.5}, part_count: false, "
        "macros: ['500-510'], pmc: [{range: R100-R139}, {range: R160, data_type: bit}, "
        "{range: D200-D203, data_type: word}]}")
WRITES = """
writes:
  enabled: true
  reconnect_deadline_s: {deadline}
  max_payload_bytes: 2048
  rate_limit: {{max_writes: 200, per_s: 60}}
  allow:
    - {{target: 'macro:500-509', min: -1000, max: 1000}}
    - {{target: 'pmc:R100-R199'}}
    - {{target: 'pmc:R300-R309', max: 100}}
    - {{target: 'pmc:D200-D203'}}
    - {{target: 'param:1825'}}
    - {{target: 'param:1815'}}
"""


def native(machine_id: str, port: int, extra: str = "") -> str:
    return f"  - {{id: {machine_id}, host: 127.0.0.1, port: {port}, {TIMEOUTS}, {POLL}{extra}}}\n"


def packed(machine_id: str, port: int | None, extra: str = "") -> str:
    poll = "poll: {periods: {status: 0.25, params: 0.5}, part_count: false, params: [{number: 1825, axis: 1}]}"
    return (f"  - {{id: {machine_id}, transport: packed, address: 'tcp:127.0.0.1:{port}', {TIMEOUTS}, "
            f"{poll}{extra}}}\n")


def config_text(broker: Mosquitto, state_dir: Path, machines: str, deadline: float = 3.0) -> str:
    return daemon_config(broker, state_dir, machines, WRITES.format(deadline=deadline))


class Running:
    """A daemon under test plus helpers to write to it like an MES would."""

    def __init__(self, daemon: Daemon, observer: Observer) -> None:
        self.daemon = daemon
        self.observer = observer
        self._next_id = 0

    async def json_write(self, machine: str, body: object, raw: bytes | None = None,
                         observer: Observer | None = None) -> Any:
        """Publish a request on <prefix>/<machine>/cmd and return the next reply."""
        topic = f"focas/{machine}/cmd/reply"
        before = len(self.observer.on(topic))
        await (observer or self.observer).publish(f"focas/{machine}/cmd",
                                                 raw if raw is not None else json.dumps(body).encode())
        replies = await self.observer.wait_topic(topic, count=before + 1, timeout=15)
        return json.loads(replies[before].payload)

    async def dcmd(self, machine: str, metrics: list[Payload.Metric]) -> None:
        payload = Payload(timestamp=int(time.time() * 1000), metrics=metrics)
        await self.observer.publish(f"spBv1.0/plant/DCMD/gw/{machine}", payload.SerializeToString(), qos=0)

    def aliases(self, machine: str) -> dict[str, int]:
        births = self.observer.on(f"spBv1.0/plant/DBIRTH/gw/{machine}")
        return {m.name: m.alias for m in births[-1].spb().metrics}

    def ddata_values(self, machine: str, name: str) -> list[object]:
        alias = self.aliases(machine)[name]
        values: list[object] = []
        for message in self.observer.on(f"spBv1.0/plant/DDATA/gw/{machine}"):
            for metric in message.spb().metrics:
                if metric.alias == alias:
                    values.append(getattr(metric, metric.WhichOneof("value") or "is_null"))
        return values

    def json_state(self, machine: str, name: str) -> list[object]:
        return [json.loads(m.payload)["value"] for m in self.observer.on(f"focas/{machine}/state/{name}")]


@pytest.fixture
async def start(observer: Observer) -> AsyncIterator[Callable[[str], Any]]:
    started: list[tuple[Daemon, asyncio.Task[int]]] = []

    async def starter(text: str, *machines: str) -> Running:
        daemon = Daemon(parse_config(text))
        started.append((daemon, asyncio.create_task(daemon.run())))
        for machine in machines:
            await observer.wait_topic(f"spBv1.0/plant/DBIRTH/gw/{machine}", timeout=15)
        return Running(daemon, observer)

    yield starter
    for daemon, task in started:
        daemon.request_stop()
        assert await asyncio.wait_for(task, 15) == 0


def ok(reply: dict[str, Any]) -> dict[str, Any]:
    assert reply["ok"] is True, reply
    assert reply["error"] is None and reply["cnc_time"], reply
    return reply


def refused(reply: dict[str, Any], code: str) -> dict[str, Any]:
    assert reply["ok"] is False, reply
    assert reply["error"]["code"] == code, reply
    return reply


def writes(machine: Machine, prefix: str = "") -> list[tuple[str, object]]:
    return [(w.target, w.new) for w in machine.state.writes(prefix)]


async def test_json_writes_of_every_kind_read_back_and_are_published(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="30i")], base_port=0,
                     packed_base_port=0) as fleet:
        fleet[1].state.set_param_write_enable(True)
        text = config_text(mosquitto, tmp_path, native("m1", fleet[0].port) + packed("m2", fleet[1].packed_port))
        run = await start(text, "m1", "m2")

        reply = ok(await run.json_write("m1", {"id": "macro", "target": "macro:500", "value": 42}))
        assert reply["id"] == "macro" and reply["value_read_back"] == 42.0
        reply = ok(await run.json_write("m1", {"id": 7, "target": "macro:501", "value": -3.125}))
        assert reply["id"] == 7 and reply["value_read_back"] == -3.125
        assert ok(await run.json_write("m1", {"target": "pmc:R120", "value": 0x41}))["value_read_back"] == 0x41
        fleet[0].state.write_pmc("R", 121, bytes([0b1000_0001]), protocol="admin")
        assert ok(await run.json_write("m1", {"target": "pmc:R121.3", "value": True}))["value_read_back"] is True
        assert fleet[0].state.read_pmc_bytes("R", 121, 121) == bytes([0b1000_1001])  # other bits kept
        block = [(i * 7) % 256 for i in range(40)]
        assert ok(await run.json_write("m1", {"target": "pmc:R140-R179", "value": block}))["value_read_back"] \
            == block
        assert writes(fleet[0], "pmc:R14") + writes(fleet[0], "pmc:R17") == [
            ("pmc:R140-R171", bytes(block[:32])), ("pmc:R172-R179", bytes(block[32:]))]  # chunked at 32
        assert ok(await run.json_write("m2", {"target": "param:1825/1", "value": 2500}))["value_read_back"] == 2500
        assert fleet[1].state.read_param_value(1825, 1) == 2500
        assert ok(await run.json_write("m2", {"target": "param:1815/1.1", "value": 1}))["value_read_back"] is True
        assert fleet[1].state.read_param_value(1815, 1) == 0b0011_0010

        # A list is applied in order and answered with a list.
        replies = await run.json_write("m1", [{"id": "a", "target": "macro:502", "value": 1},
                                              {"id": "b", "target": "macro:502", "value": 2}])
        assert [r["id"] for r in replies] == ["a", "b"] and all(r["ok"] for r in replies)
        assert writes(fleet[0], "macro:502") == [("macro:502", 1.0), ("macro:502", 2.0)]

        # Every value shows up in the published data (read back and reported at once).
        await async_wait_for(lambda: 42.0 in run.json_state("m1", "Macro/500"), message="Macro/500 published")
        await async_wait_for(lambda: -3.125 in run.ddata_values("m1", "Macro/501"), message="Macro/501 DDATA")
        await async_wait_for(lambda: 0x41 in run.ddata_values("m1", "PMC/R120"), message="PMC/R120 DDATA")
        await async_wait_for(lambda: 2500.0 in run.json_state("m2", "Param/1825/1"), message="param published")
    audit = [json.loads(line) for line in (tmp_path / "write-audit.jsonl").read_text().splitlines()]
    assert {a["outcome"] for a in audit} == {"ok"} and len(audit) == 9
    assert audit[0]["target"] == "macro:500" and audit[0]["old"] == 12.5 and audit[0]["new"] == 42.0
    assert audit[0]["topic"] == "focas/m1/cmd" and audit[0]["source"] == "json"


async def test_dcmd_writes_by_name_and_alias_read_back_in_ddata(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="30i")], base_port=0,
                     packed_base_port=0) as fleet:
        fleet[1].state.set_param_write_enable(True)
        text = config_text(mosquitto, tmp_path, native("m1", fleet[0].port) + packed("m2", fleet[1].packed_port))
        run = await start(text, "m1", "m2")
        aliases = run.aliases("m1")

        await run.dcmd("m1", [Payload.Metric(name="Macro/503", datatype=DataType.Double, double_value=7.0)])
        await run.dcmd("m1", [Payload.Metric(alias=aliases["Macro/504"], double_value=0.333)])
        await run.dcmd("m1", [Payload.Metric(alias=aliases["PMC/R105"], int_value=0x5A)])
        # One DCMD carrying 40 adjacent PMC bytes is one 40-byte write, sent as 32 + 8.
        block = [(200 - i) for i in range(40)]
        await run.dcmd("m1", [Payload.Metric(alias=aliases[f"PMC/R{100 + i}"], int_value=v)
                              for i, v in enumerate(block)])
        await run.dcmd("m2", [Payload.Metric(alias=run.aliases("m2")["Param/1825/1"], double_value=2600.0)])

        await async_wait_for(lambda: 7.0 in run.ddata_values("m1", "Macro/503"), message="Macro/503 DDATA")
        await async_wait_for(lambda: 0.333 in run.ddata_values("m1", "Macro/504"), message="Macro/504 DDATA")
        await async_wait_for(lambda: 2600.0 in run.ddata_values("m2", "Param/1825/1"), message="param DDATA")
        await async_wait_for(lambda: block[39] in run.ddata_values("m1", "PMC/R139"), message="PMC DDATA")
        assert writes(fleet[0], "macro:") == [("macro:503", 7.0), ("macro:504", 0.333)]
        assert writes(fleet[0], "pmc:") == [("pmc:R105", bytes([0x5A])), ("pmc:R100-R131", bytes(block[:32])),
                                            ("pmc:R132-R139", bytes(block[32:]))]
        assert writes(fleet[1], "param:") == [("param:1825/1", 2600)]
        assert run.daemon.commands.counters["writes_ok"] == 5


async def test_refused_writes_answer_their_code_and_leave_the_cnc_untouched(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i"), MachineSpec(profile="30i"), MachineSpec(profile="30i")],
                     base_port=0) as fleet:
        machines = (native("m1", fleet[0].port) + native("locked", fleet[1].port, ", writes: {enabled: false}")
                    + native("slow", fleet[2].port, ", writes: {rate_limit: {max_writes: 2, per_s: 600}}"))
        run = await start(config_text(mosquitto, tmp_path, machines), "m1", "locked", "slow")

        refused(await run.json_write("locked", {"id": 1, "target": "macro:500", "value": 1}), "disabled")
        refused(await run.json_write("m1", {"target": "macro:600", "value": 1}), "not_allowed")
        refused(await run.json_write("m1", {"target": "param:6711", "value": 1}), "not_allowed")
        refused(await run.json_write("m1", {"target": "macro:500", "value": 5000}), "out_of_bounds")
        refused(await run.json_write("m1", {"target": "macro:500", "value": "12"}), "wrong_type")
        refused(await run.json_write("m1", {"target": "pmc:R100", "value": 300}), "wrong_type")
        refused(await run.json_write("m1", {"target": "pmc:R100-R103", "value": [1, 2]}), "wrong_type")
        refused(await run.json_write("m1", {"target": "pmc:Q100", "value": 1}), "invalid_target")
        refused(await run.json_write("m1", None, raw=b'{"target": "macro:500", "value": '), "malformed")
        refused(await run.json_write("m1", {"target": "macro:500", "value": 1, "color": "red"}), "malformed")
        big = {"id": "x" * 3000, "target": "macro:500", "value": 1}
        refused(await run.json_write("m1", big), "payload_too_large")
        # One refused write in a list: nothing of the list is written.
        replies = await run.json_write("m1", [{"id": "a", "target": "macro:500", "value": 1},
                                              {"id": "b", "target": "macro:600", "value": 1}])
        assert [r["error"]["code"] for r in replies] == ["skipped", "not_allowed"]
        # Sparkplug: unknown alias, wrong type, read-only metric: no write, counted.
        before = run.daemon.publisher.counters
        await run.dcmd("m1", [Payload.Metric(alias=987_654, double_value=1.0)])
        await run.dcmd("m1", [Payload.Metric(name="Macro/500", string_value="twelve")])
        await run.dcmd("m1", [Payload.Metric(name="Status/Run", string_value="START")])
        await async_wait_for(lambda: run.daemon.publisher.counters["unknown_commands"]
                             == before["unknown_commands"] + 1, message="unknown alias counted")
        await async_wait_for(lambda: run.daemon.publisher.counters["rejected_commands"]
                             == before["rejected_commands"] + 2, message="wrong type and read-only counted")
        await run.dcmd("m1", [Payload.Metric(name="Macro/500", double_value=5000.0)])  # beyond the bounds
        await async_wait_for(lambda: run.daemon.commands.counters["outcome/out_of_bounds"] == 2,
                             message="DCMD out of bounds refused")
        assert all(m.state.write_log == [] for m in fleet), [m.state.write_log for m in fleet]

        # Rate limit: 2 writes per 600 s on "slow"; the third is refused and not written.
        for value in (1, 2):
            ok(await run.json_write("slow", {"target": "macro:505", "value": value}))
        refused(await run.json_write("slow", {"target": "macro:505", "value": 3}), "rate_limited")
        assert writes(fleet[2]) == [("macro:505", 1.0), ("macro:505", 2.0)]
    audit = [json.loads(line) for line in (tmp_path / "write-audit.jsonl").read_text().splitlines()]
    outcomes = [a["outcome"] for a in audit]
    assert outcomes.count("malformed") == 2 and outcomes.count("rate_limited") == 1
    assert outcomes.count("payload_too_large") == 1 and outcomes.count("disabled") == 1


async def test_parameter_write_switch_and_native_transport(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0, packed_base_port=0) as fleet:
        machines = packed("m2", fleet[0].packed_port) + native("m1", fleet[0].port)
        run = await start(config_text(mosquitto, tmp_path, machines), "m1", "m2")
        fleet[0].state.set_param_write_enable(False)
        reply = refused(await run.json_write("m2", {"target": "param:1825/1", "value": 1234}), "access_denied")
        assert "PASSWD" in reply["error"]["message"] or "11" in reply["error"]["message"]
        assert fleet[0].state.writes("param:") == []
        fleet[0].state.set_param_write_enable(True)
        ok(await run.json_write("m2", {"target": "param:1825/1", "value": 1234}))
        assert writes(fleet[0], "param:") == [("param:1825/1", 1234)]
        refused(await run.json_write("m2", {"target": "param:1825/1", "value": 70000}), "wrong_type")
        refused(await run.json_write("m2", {"target": "param:1825", "value": 1}), "invalid_target")  # per axis
        refused(await run.json_write("m1", {"target": "param:1825/1", "value": 1}), "not_supported")
        assert len(fleet[0].state.writes("param:")) == 1


async def test_write_waits_for_reconnect_within_deadline_else_fails_cleanly(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        run = await start(config_text(mosquitto, tmp_path, native("m1", fleet[0].port), deadline=2.0), "m1")
        commands = run.daemon.commands

        async def cnc_away() -> None:
            deaths = len(run.observer.on("spBv1.0/plant/DDEATH/gw/m1"))
            fleet[0].faults.update({"refuse": -1})
            fleet[0].drop_connections()
            await run.observer.wait_topic("spBv1.0/plant/DDEATH/gw/m1", count=deaths + 1, timeout=10)

        await cnc_away()
        requests = commands.counters["requests"]
        pending = asyncio.create_task(run.json_write("m1", {"target": "macro:506", "value": 6}))
        await async_wait_for(lambda: commands.counters["requests"] > requests, message="request received")
        assert fleet[0].state.writes() == []
        fleet[0].faults.clear()  # the CNC comes back within the deadline
        reply = ok(await pending)
        assert reply["value_read_back"] == 6.0 and writes(fleet[0]) == [("macro:506", 6.0)]

        await cnc_away()
        started = time.monotonic()
        reply = refused(await run.json_write("m1", {"target": "macro:506", "value": 7}), "unavailable")
        assert 1.5 < time.monotonic() - started < 6, "failed at the 2 s deadline"
        assert "nothing was written" in reply["error"]["message"]
        fleet[0].faults.clear()
        await run.observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=3, timeout=10)
        assert writes(fleet[0]) == [("macro:506", 6.0)]  # the failed write is not sent later either


def lose_answer_after_next_macro_write(machine: Machine) -> None:
    """The simulator applies the next macro write, then sends half its answer and falls silent (the
    `hang_on` fault aims the hang at that function only, never at a poll)."""
    machine.faults.update({"hang_on": {"write_macros": 1}})  # 0x16, the client's form for this value


async def test_write_whose_answer_is_lost_is_reread_not_repeated(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        run = await start(config_text(mosquitto, tmp_path, native("m1", fleet[0].port)), "m1")
        lose_answer_after_next_macro_write(fleet[0])
        reply = ok(await run.json_write("m1", {"id": "lost", "target": "macro:507", "value": 77.5}))
        assert reply["value_read_back"] == 77.5
        assert "re-read shows the value was applied" in reply["note"]
        assert writes(fleet[0]) == [("macro:507", 77.5)], "sent exactly once"
        await async_wait_for(lambda: 77.5 in run.json_state("m1", "Macro/507"), message="published")


async def test_concurrent_bit_writes_to_one_byte_from_two_clients_both_land(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        run = await start(config_text(mosquitto, tmp_path, native("m1", fleet[0].port)), "m1")
        second = Observer(mosquitto, topics=("focas/m1/cmd/reply",))
        try:
            bits = [(run.observer, 0), (second, 1), (run.observer, 2), (second, 3)]
            await asyncio.gather(*(client.publish("focas/m1/cmd", json.dumps(
                {"id": f"bit{bit}", "target": f"pmc:R150.{bit}", "value": True}).encode())
                for client, bit in bits))
            await run.observer.wait_topic("focas/m1/cmd/reply", count=4, timeout=15)
        finally:
            second.close()
        replies = [json.loads(m.payload) for m in run.observer.on("focas/m1/cmd/reply")]
        assert sorted(r["id"] for r in replies if r["ok"]) == ["bit0", "bit1", "bit2", "bit3"]
        assert fleet[0].state.read_pmc_bytes("R", 150, 150) == bytes([0b0000_1111])


async def test_dcmd_bit_write_sets_one_pmc_bit_and_keeps_the_others(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        fleet[0].state.write_pmc("R", 160, bytes([0b1000_0001]), protocol="admin")
        run = await start(config_text(mosquitto, tmp_path, native("m1", fleet[0].port)), "m1")
        aliases = run.aliases("m1")
        assert {f"PMC/R160.{b}" for b in range(8)} <= set(aliases)
        await run.dcmd("m1", [Payload.Metric(alias=aliases["PMC/R160.3"], boolean_value=True)])
        await async_wait_for(lambda: True in run.ddata_values("m1", "PMC/R160.3"), message="bit 3 in DDATA")
        assert fleet[0].state.read_pmc_bytes("R", 160, 160) == bytes([0b1000_1001])
        # the admin seed, then exactly one read-modify-write of the byte
        assert writes(fleet[0], "pmc:R160") == [("pmc:R160", bytes([0b1000_0001])), ("pmc:R160", bytes([0b1000_1001]))]


def audit_lines(state_dir: Path) -> list[dict[str, Any]]:
    path = state_dir / "write-audit.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


async def test_every_command_gets_an_answer_and_an_audit_line_and_nothing_wraps(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        run = await start(config_text(mosquitto, tmp_path, native("m1", fleet[0].port)), "m1")
        aliases = run.aliases("m1")
        audited = len(audit_lines(tmp_path))

        # JSON nested ~1000 levels used to kill the handler: no reply, no audit line.
        reply = refused(await run.json_write("m1", None, raw=b"[" * 1000 + b"]" * 1000), "malformed")
        assert "nested" in reply["error"]["message"]
        reply = refused(await run.json_write("nope", {"id": "q1", "target": "macro:500", "value": 1}),
                        "unknown_machine")
        assert reply["id"] == "q1" and reply["target"] == "macro:500"
        reply = refused(await run.json_write("m1", {"target": "macro:500", "value": "12"}), "wrong_type")
        assert "expected a number" in reply["error"]["message"]
        # Bounds hold for the number the CNC would hold: -1 is the byte 255.
        reply = refused(await run.json_write("m1", {"target": "pmc:R300", "value": -1}), "out_of_bounds")
        assert "255" in reply["error"]["message"]

        # DCMD refusals by the publisher are audit lines too; 70000 for an Int16 word is refused, not 4464.
        await run.dcmd("m1", [Payload.Metric(alias=aliases["PMC/D200"], int_value=70000)])
        await run.dcmd("m1", [Payload.Metric(alias=aliases["PMC/D200"], int_value=(-40000) & 0xFFFFFFFF)])
        await run.dcmd("m1", [Payload.Metric(alias=987_654, double_value=1.0)])
        await run.dcmd("m1", [Payload.Metric(name="Status/Run", string_value="START")])
        await run.dcmd("m1", [Payload.Metric(name="Macro/500", string_value="twelve")])
        await run.dcmd("ghost", [Payload.Metric(name="Macro/500", double_value=1.0)])
        await async_wait_for(lambda: len(audit_lines(tmp_path)) >= audited + 10, message="ten audit lines")
        lines = audit_lines(tmp_path)[audited:]
        assert [a["outcome"] for a in lines] == [
            "malformed", "unknown_machine", "wrong_type", "out_of_bounds",
            "wrong_type", "wrong_type", "unknown_metric", "invalid_target", "wrong_type", "unknown_machine"]
        assert lines[1]["request_id"] == "q1" and lines[1]["target"] == "macro:500"
        assert lines[4]["source"] == "sparkplug" and lines[4]["target"] == "PMC/D200" and "70000" in lines[4]["message"]
        assert lines[9]["machine"] == "ghost"
        assert run.daemon.commands.counters["outcome/wrong_type"] >= 4
        await asyncio.sleep(0)
        assert fleet[0].state.write_log == []


async def test_one_dcmd_is_one_command_capped_like_json_and_audited_once_when_refused(
        mosquitto: Mosquitto, start: Callable[..., Any], tmp_path: Path) -> None:
    """A 580 kB DCMD of 5,000 unknown names used to write 5,000 audit lines (2.3 MB)."""
    async with Fleet([MachineSpec(profile="30i")], base_port=0) as fleet:
        run = await start(config_text(mosquitto, tmp_path, native("m1", fleet[0].port)), "m1")
        aliases = run.aliases("m1")
        audit_file = tmp_path / "write-audit.jsonl"
        audited, size = len(audit_lines(tmp_path)), audit_file.stat().st_size if audit_file.exists() else 0

        flood = [Payload.Metric(name=f"Unknown/Metric{n:04d}/{'x' * 90}", double_value=1.0) for n in range(5000)]
        assert len(Payload(metrics=flood).SerializeToString()) > 500_000
        await run.dcmd("m1", flood)
        # 65 writable metrics in ~1 kB: under the byte cap (2048 here), over the 64-write cap.
        await run.dcmd("m1", [Payload.Metric(alias=aliases[f"PMC/R{100 + n % 40}"], int_value=1) for n in range(65)])
        # One unknown name among good ones: the whole DCMD is refused, nothing of it written.
        await run.dcmd("m1", [Payload.Metric(alias=aliases["Macro/500"], double_value=3.0),
                              Payload.Metric(name="No/Such", double_value=1.0)])
        await run.dcmd("m1", [Payload.Metric(alias=aliases["Macro/501"], double_value=4.0)])
        await async_wait_for(lambda: len(audit_lines(tmp_path)) >= audited + 4, message="four audit lines")
        lines = audit_lines(tmp_path)[audited:]
        assert [a["outcome"] for a in lines] == ["payload_too_large", "malformed", "unknown_metric", "ok"], lines
        assert "5000 writes in this command, none sent" in lines[0]["message"]
        assert "65 metrics in one DCMD; at most 64" in lines[1]["message"]
        assert lines[2]["target"] == "No/Such" and "2 writes in this command, none sent" in lines[2]["message"]
        assert audit_file.stat().st_size - size < 4000, "four lines, not megabytes"
        assert writes(fleet[0], "macro:") == [("macro:501", 4.0)] and writes(fleet[0], "pmc:") == []
