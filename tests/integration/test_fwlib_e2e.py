"""End to end through the library host: daemon (transport: packed) -> fwlib-host -> the stand-in library.

Alarm history comes out of the library's ODBAHIS structs as events stamped with the CNC's occurrence
times, once (the persisted dedup watermark holds across a daemon restart); a history call that hangs is a
counted, visible error of that function until it answers, and then its entries arrive once; parameter
writes through JSON and DCMD land in the stand-in's memory and are read back.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from datetime import UTC, datetime
from pathlib import Path

import pytest

from edge.config import parse_config
from edge.focas import packed as pk
from edge.fwlib.host import FwlibHost, start_host
from edge.fwlib.library import load_library
from edge.fwlib.settings import HostSettings
from edge.publish.sparkplug_b_pb2 import Payload
from edge.service.daemon import Daemon
from tests.fwlib.standin import Standin, standin_library
from tests.helpers import Mosquitto, async_wait_for, free_port
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer
from tests.integration.test_status_http import http_get, samples

pytestmark = pytest.mark.integration

TWO_WORD = 3
TIMEOUTS = "timeouts: {request_s: 2, connect_s: 2, backoff_initial_s: 0.05, backoff_max_s: 0.3}"
ALARMS = "alarms: {mode: ActivePlusHistory, history_interval: 0.5s}"
WRITES = """
writes:
  enabled: true
  allow:
    - {target: 'param:6711'}
"""


@pytest.fixture
def standin() -> Standin:
    return Standin(standin_library())


@pytest.fixture
async def host(standin: Standin, tmp_path: Path) -> AsyncIterator[FwlibHost]:
    settings = HostSettings.model_validate({
        "library": standin_library(), "log_file": str(tmp_path / "focas.log"), "call_timeout_s": 5,
        "machines": [{"name": "m1", "cnc": "10.0.0.1", "listen": f"unix:{tmp_path}/m1.sock",
                      "params": {6711: "two_word"}}],
    })
    running = await start_host(settings, load_library(standin_library()))
    try:
        await asyncio.wait_for(running.workers["m1"].wait_available(), 10)
        yield running
    finally:
        await running.close()


def machine(host: FwlibHost) -> str:
    poll = "poll: {periods: {status: 0.25, params: 0.25}, part_count: false, params: [{number: 6711}]}"
    return (f"  - {{id: m1, transport: packed, address: '{host.endpoints['m1'].address}', {TIMEOUTS}, "
            f"{poll}}}\n")


async def run_daemon(text: str, observer: Observer, births: int) -> tuple[Daemon, asyncio.Task[int]]:
    daemon = Daemon(parse_config(text))
    task = asyncio.create_task(daemon.run())
    await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", count=births, timeout=15)
    return daemon, task


async def stop(daemon: Daemon, task: asyncio.Task[int]) -> None:
    daemon.request_stop()
    assert await asyncio.wait_for(task, 15) == 0


def history(observer: Observer) -> list[dict[str, object]]:
    docs = [json.loads(m.payload) for m in observer.on("focas/m1/events/alarm")]
    return [json.loads(d["value"]) for d in docs if d["name"] == "Alarm/History"]


async def more_history_reads(host: FwlibHost) -> None:
    """Wait for a few more history reads at the host: time for an entry to come twice, if it would."""
    reads = host.endpoints["m1"].requests_for
    polls = len(reads(pk.Command.RDALMHISTRY))
    await async_wait_for(lambda: len(reads(pk.Command.RDALMHISTRY)) > polls + 3, timeout=15,
                         message="more history reads")


async def test_alarm_history_from_the_library_is_published_once_with_cnc_times(
        standin: Standin, host: FwlibHost, mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    standin.push_alarm((2026, 11, 20, 6, 30, 0), 1001, b"SERVO ALARM X", group=6)
    standin.push_alarm((2026, 11, 21, 7, 45, 12), 2002, b"", group=2)
    text = daemon_config(mosquitto, tmp_path, machine(host), ALARMS)

    daemon, task = await run_daemon(text, observer, births=1)
    try:
        await async_wait_for(lambda: len(history(observer)) >= 2, timeout=15, message="history events")
    finally:
        await stop(daemon, task)
    first = history(observer)
    expected_ms = [int(datetime(2026, 11, 20, 6, 30, tzinfo=UTC).timestamp() * 1000),
                   int(datetime(2026, 11, 21, 7, 45, 12, tzinfo=UTC).timestamp() * 1000)]
    assert sorted(int(e["occurred_ms"]) for e in first) == expected_ms  # type: ignore[call-overload]
    assert {(e["number"], e["message"]) for e in first} == {(1001, "SERVO ALARM X"), (2002, "")}
    watermark = json.loads((tmp_path / "alarm-history" / "m1.json").read_text())
    assert watermark["time_ms"] == expected_ms[1] and watermark["keys_at_time"] == {f"{expected_ms[1]}:2:2002": 1}

    # A restarted daemon publishes only what is new in the library's ring.
    daemon, task = await run_daemon(text, observer, births=2)
    try:
        standin.push_alarm((2026, 11, 22, 8, 0, 0), 3003, b"NEW ONE", group=4)
        await async_wait_for(lambda: len(history(observer)) > len(first), timeout=15, message="the new alarm")
        await more_history_reads(host)
    finally:
        await stop(daemon, task)
    assert [e["number"] for e in history(observer)[len(first):]] == [3003]


def history_quality(observer: Observer) -> str | None:
    """The quality of the retained JSON state of Alarm/History (the history read's own metric), last sent."""
    docs = observer.on("focas/m1/state/Alarm/History")
    return str(json.loads(docs[-1].payload)["quality"]) if docs else None


async def test_history_call_that_hangs_is_a_counted_visible_error_then_its_entries_arrive_once(
        standin: Standin, mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """Issue 24: cnc_rdalmhistry3 hangs in the library; the host answers EW_SOCKET. That is an error of
    ReadAlarmHistory in /metrics, on the status page and in last_error, and Alarm/History is BAD, instead of
    an empty history; once the call answers, every entry is published once."""
    settings = HostSettings.model_validate({
        "library": standin_library(), "log_file": str(tmp_path / "focas.log"), "call_timeout_s": 0.5,
        "hung_rest_s": 0.2, "backoff_initial_s": 0.05, "backoff_max_s": 0.2,
        "machines": [{"name": "m1", "cnc": "10.0.0.1", "listen": f"unix:{tmp_path}/m1.sock"}],
    })
    host = await start_host(settings, load_library(standin_library()))
    try:
        await asyncio.wait_for(host.workers["m1"].wait_available(), 10)
        standin.set_history_version(3)  # cnc_rdalmhistry4 answers EW_FUNC: the host uses cnc_rdalmhistry3
        standin.push_alarm((2026, 11, 20, 6, 30, 0), 1001, b"SERVO ALARM X", group=6)
        standin.push_alarm((2026, 11, 21, 7, 45, 12), 2002, b"OVERTRAVEL", group=2)
        standin.hang_history(-1)
        http_port = free_port()
        extra = f"{ALARMS}\nhttp: {{enabled: true, host: 127.0.0.1, port: {http_port}}}"
        daemon, task = await run_daemon(daemon_config(mosquitto, tmp_path, machine(host), extra), observer, 1)
        try:
            await async_wait_for(lambda: history_quality(observer) == "BAD", timeout=15,
                                 message="Alarm/History published BAD while the history call hangs")
            poller = daemon.pollers["m1"]
            await async_wait_for(lambda: poller.stats.errors.get(("ReadAlarmHistory", "EW_SOCKET"), 0) >= 2
                                 and "ReadAlarmHistory" in poller.last_error, timeout=15,
                                 message="history errors counted, the last error")
            assert "EW_SOCKET" in poller.last_error and "cnc_rdalmhistry" in poller.last_error
            metrics = samples((await http_get(http_port, "/metrics"))[2].decode())
            assert metrics[("focas_edge_cnc_errors_total",
                            (("code", "EW_SOCKET"), ("function", "ReadAlarmHistory"), ("machine", "m1")))] >= 2
            assert metrics[("focas_edge_function_failing",
                            (("function", "ReadAlarmHistory"), ("machine", "m1")))] == 1
            [m1] = json.loads((await http_get(http_port, "/status.json"))[2])["machines"]
            [failing] = [f for f in m1["failing"] if f["function"] == "ReadAlarmHistory"]
            assert failing["errors"] >= 2 and "EW_SOCKET" in failing["error"]
            assert "ReadAlarmHistory failing since" in (await http_get(http_port, "/"))[2].decode()
            assert history(observer) == []

            standin.hang_history(0)  # the call answers again
            standin.release()
            await async_wait_for(lambda: len(history(observer)) >= 2, timeout=15, message="the entries")
            await async_wait_for(lambda: history_quality(observer) == "GOOD", timeout=15,
                                 message="Alarm/History GOOD again")
            assert "ReadAlarmHistory" not in poller.stats.failing
            await more_history_reads(host)
        finally:
            await stop(daemon, task)
    finally:
        standin.release()
        await host.close()
    assert sorted((e["number"], e["message"]) for e in history(observer)) == [(1001, "SERVO ALARM X"),
                                                                           (2002, "OVERTRAVEL")]


async def test_parameter_writes_through_json_and_dcmd_reach_the_library_and_read_back(
        standin: Standin, host: FwlibHost, mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    standin.set_param(6711, TWO_WORD, 100)
    text = daemon_config(mosquitto, tmp_path, machine(host), WRITES)
    daemon, task = await run_daemon(text, observer, births=1)
    try:
        await observer.publish("focas/m1/cmd", json.dumps({"id": "p", "target": "param:6711",
                                                           "value": 123456}).encode())
        [reply] = await observer.wait_topic("focas/m1/cmd/reply", count=1, timeout=15)
        answer = json.loads(reply.payload)
        assert answer["ok"] is True and answer["value_read_back"] == 123456, answer
        assert standin.param(6711) == 123456

        birth = observer.on("spBv1.0/plant/DBIRTH/gw/m1")[-1].spb()
        alias = {m.name: m.alias for m in birth.metrics}["Param/6711"]
        dcmd = Payload(metrics=[Payload.Metric(alias=alias, double_value=-42.0)])
        await observer.publish("spBv1.0/plant/DCMD/gw/m1", dcmd.SerializeToString(), qos=0)
        await async_wait_for(lambda: standin.param(6711) == -42, timeout=15, message="DCMD write in the library")

        def published() -> list[object]:
            return [json.loads(m.payload)["value"] for m in observer.on("focas/m1/state/Param/6711")]

        await async_wait_for(lambda: -42 in published(), timeout=15, message="read back and published")
    finally:
        await stop(daemon, task)
