"""Writes that name their CNC path (`macro:500@2`, "path": 2) on the machine's own command topic, and the
CLI's `@N`: the two-path lathe simulator over TCP, the daemon, a real mosquitto."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from edge.cli import main
from edge.cli.read import EXIT_USAGE
from edge.config import parse_config
from edge.service.daemon import Daemon
from edge.sim.fleet import Fleet, FleetThread, MachineSpec
from tests.helpers import Mosquitto, async_wait_for
from tests.integration.daemon_config import daemon_config
from tests.integration.mqtt_observer import Observer

pytestmark = pytest.mark.integration

WRITES = "writes: {enabled: true, allow: [{target: 'macro:500-599'}]}\n"


async def _request(observer: Observer, topic: str, body: object) -> object:
    """Publish one request on `topic` and return its reply (the next message on `<topic>/reply`)."""
    before = len(observer.on(f"{topic}/reply"))
    await observer.publish(topic, json.dumps(body).encode())
    await async_wait_for(lambda: len(observer.on(f"{topic}/reply")) > before, timeout=15,
                         message=f"a reply on {topic}/reply")
    return json.loads(observer.on(f"{topic}/reply")[before].payload)


def _audit(state_dir: Path) -> list[dict[str, object]]:
    path = state_dir / "write-audit.jsonl"
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()] if path.exists() else []


async def test_a_write_names_its_path_on_the_machines_own_command_topic(
        mosquitto: Mosquitto, observer: Observer, tmp_path: Path) -> None:
    """`@2` and "path": 2 on `focas/m1/cmd` land on path 2, a write without either on path 1; a path beyond
    `paths: 2` is refused as unknown_path (audited, nothing written, nor the rest of its list); `@2` with
    "path": 1 is malformed."""
    async with Fleet([MachineSpec(profile="31i-2p")], base_port=0) as fleet:
        machines = (f"  - {{id: m1, host: 127.0.0.1, port: {fleet[0].port}, paths: 2, "
                    f"poll: {{periods: {{status: 0.1s}}}}}}\n")
        daemon = Daemon(parse_config(daemon_config(mosquitto, tmp_path, machines, WRITES)))
        task = asyncio.create_task(daemon.run())
        first = fleet[0].state
        second = first.for_path(2)
        assert second is not None
        try:
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1-path2", timeout=15)
            await observer.wait_topic("spBv1.0/plant/DBIRTH/gw/m1", timeout=15)
            replies = await _request(observer, "focas/m1/cmd", [
                {"id": "a", "target": "macro:530@2", "value": 3.25},
                {"id": "b", "target": "macro:531", "path": 2, "value": 1.5},
                {"id": "c", "target": "macro:532", "value": 2.0}])
            assert isinstance(replies, list)
            assert [(r["id"], r["ok"], r["target"]) for r in replies] == [
                ("a", True, "macro:530@2"), ("b", True, "macro:531@2"), ("c", True, "macro:532")], replies
            assert (second.read_macro(530), second.read_macro(531)) == (3.25, 1.5)
            assert first.read_macro(530) != 3.25 and first.read_macro(531) != 1.5
            assert first.read_macro(532) == 2.0 and second.read_macro(532) != 2.0

            beyond = await _request(observer, "focas/m1/cmd", {"id": "x", "target": "macro:533@3", "value": 9.0})
            assert isinstance(beyond, dict) and beyond["ok"] is False
            assert beyond["error"]["code"] == "unknown_path", beyond
            assert "paths: 2" in beyond["error"]["message"]
            assert first.read_macro(533) != 9.0 and second.read_macro(533) != 9.0
            assert any(line["request_id"] == "x" and line["outcome"] == "unknown_path" for line in _audit(tmp_path))

            mixed = await _request(observer, "focas/m1/cmd", [
                {"id": "m", "target": "macro:535", "value": 9.0}, {"id": "n", "target": "macro:536@3", "value": 9.0}])
            assert isinstance(mixed, list)
            assert [r["error"]["code"] for r in mixed] == ["skipped", "unknown_path"], mixed
            assert first.read_macro(535) != 9.0, "a list with a refused write writes nothing"

            both = await _request(observer, "focas/m1/cmd",
                                  {"id": "y", "target": "macro:534@2", "path": 1, "value": 9.0})
            assert isinstance(both, dict) and both["error"]["code"] == "malformed", both
            assert first.read_macro(534) != 9.0 and second.read_macro(534) != 9.0
        finally:
            daemon.request_stop()
            assert await asyncio.wait_for(task, 20) == 0


def test_cli_items_name_their_path_with_at(capsys: pytest.CaptureFixture[str]) -> None:
    """`macro:511@2=6.5` writes path 2 and `program@2` reads it, like --path 2; an `@N` that disagrees with
    --path is a usage error and writes nothing."""
    with FleetThread(Fleet([MachineSpec(profile="31i-2p")], base_port=0)) as fleet:
        state = fleet[0].state
        second = state.for_path(2)
        assert second is not None
        address = f"127.0.0.1:{fleet[0].port}"
        assert main(["--log-level", "WARNING", "write", address, "macro:511@2=6.5"]) == 0
        assert main(["--log-level", "WARNING", "read", "--json", address, "program@2"]) == 0
        out = capsys.readouterr().out.splitlines()[-1]
        assert main(["--log-level", "WARNING", "write", "--path", "1", address, "macro:512@2=6.5"]) == EXIT_USAGE
        assert "names path 2 but --path 1" in capsys.readouterr().err
    assert json.loads(out)["value"]["running"] == second.program_numbers().running
    assert second.read_macro(511) == 6.5 and state.read_macro(511) != 6.5
    assert second.read_macro(512) != 6.5 and state.read_macro(512) != 6.5
