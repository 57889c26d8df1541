"""The top level: documented defaults, devices per CNC path, state_dir, http/spool, the poll grid."""

from __future__ import annotations

from pathlib import Path

import pytest

from edge.config import DEFAULT_STATE_DIR
from tests.unit.config.minimal import MINIMAL, parse, problems_of


def test_minimal_config_gets_the_documented_defaults() -> None:
    config = parse(MINIMAL)
    machine = config.machines[0]
    assert machine.port == 8193 and machine.transport == "focas" and machine.timezone == "UTC"
    assert machine.endpoint == "10.0.0.1:8193"
    assert machine.poll.periods.status == 0.25
    assert machine.poll.periods.macros == 1.0 and machine.poll.periods.pmc == 1.0
    assert machine.poll.periods.params == 60.0
    assert machine.max_skew_s == 60.0
    assert config.alarms.mode == "ActiveOnly"
    assert config.alarms.history_interval == 300.0 and config.alarms.history_depth == 100
    assert config.writes.enabled is False
    assert config.http.enabled is False and config.http.host == "127.0.0.1"
    assert config.mqtt.protocol == "3.1.1" and config.mqtt.effective_port == 1883
    assert config.mqtt.formats == ["sparkplug", "json"]
    assert config.mqtt.json_prefix == "focas/g/n"  # the gateway's identity (docs/topics.md)
    assert config.resolved_state_dir == DEFAULT_STATE_DIR
    assert config.warnings == []


def test_paths_expand_to_one_device_per_path() -> None:
    two_paths = MINIMAL + "    paths: 2\n"
    config = parse(two_paths)
    assert [(d.id, d.path) for d in config.devices()] == [("m1", 1), ("m1-path2", 2)]
    assert config.machine("m1-path2").host == "10.0.0.1"
    clash = problems_of(two_paths + "  - {id: m1-path2, host: 10.0.0.2}\n")
    assert any("its path 2 is the device 'm1-path2', already a machine id" in p for p in clash), clash
    packed = problems_of(MINIMAL.replace("    host: 10.0.0.1\n",
                                         "    transport: packed\n    address: unix:/run/x.sock\n    paths: 2\n"))
    assert any("paths: only for transport focas" in p for p in packed), packed


def test_state_dir_precedence() -> None:
    assert parse(MINIMAL, {"STATE_DIRECTORY": "/var/lib/x:/var/lib/y"}).resolved_state_dir == Path("/var/lib/x")
    explicit = parse(MINIMAL + "state_dir: /srv/edge\n", {"STATE_DIRECTORY": "/var/lib/x"})
    assert explicit.resolved_state_dir == Path("/srv/edge")


def test_other_sections() -> None:
    config = parse(MINIMAL + "spool: {max_bytes: 64MiB, max_age_s: 2d}\nhttp: {enabled: true, port: 9200}\n")
    assert config.spool.max_bytes == 64 * 1024 * 1024 and config.spool.max_age_s == 2 * 86400
    assert config.http.enabled and config.http.port == 9200 and config.http.healthy_share == 0.5
    assert parse(MINIMAL.replace("host: broker", "host: broker\n  protocol: 5")).mqtt.protocol == "5"
    assert any(p.startswith("mqtt.protocol") for p in problems_of(MINIMAL.replace(
        "host: broker", "host: broker\n  protocol: 4")))


def test_poll_grid_takes_a_duration() -> None:
    config = parse(MINIMAL + "poll_grid_s: 30ms\n")
    assert config.poll_grid_s == config.poll_grid_step_s == 0.03


@pytest.mark.parametrize("setting", ["", "poll_grid_s: auto\n", "poll_grid_s: AUTO\n"])
def test_poll_grid_auto_is_half_the_fastest_period_capped_at_50_ms(setting: str) -> None:
    assert parse(MINIMAL + setting).poll_grid_s is None
    assert parse(MINIMAL + setting).poll_grid_step_s == 0.05  # default periods: status 250 ms
    fast = MINIMAL + "    poll: {periods: {status: 80ms}}\n" + setting
    assert parse(fast).poll_grid_step_s == pytest.approx(0.04)


def test_poll_grid_auto_follows_the_fastest_machine_of_the_fleet() -> None:
    text = MINIMAL + "    poll: {periods: {status: 1s}}\n  - {id: m2, host: 10.0.0.2, poll: {periods: {pmc: 60ms}}}\n"
    assert parse(text).poll_grid_step_s == pytest.approx(0.03)


@pytest.mark.parametrize("grid,message", [
    ("0", "greater than 0"),
    ("200ms", "less than or equal to 0.1"),
    ("soon", "expected a duration"),
])
def test_poll_grid_out_of_range_is_refused(grid: str, message: str) -> None:
    problems = problems_of(MINIMAL + f"poll_grid_s: {grid}\n")
    assert any("poll_grid_s" in p and message in p for p in problems), problems


def test_poll_grid_coarser_than_half_a_period_is_refused_naming_the_machine() -> None:
    text = MINIMAL + "    poll: {periods: {status: 80ms}}\npoll_grid_s: 50ms\n"
    problems = problems_of(text)
    assert any("poll_grid_s 0.05s is more than half of machine 'm1'" in p and "0.04s" in p for p in problems), problems
