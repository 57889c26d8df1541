"""`machines:`: ids, endpoints per transport, subpackets, alarm history depth."""

from __future__ import annotations

import pytest

from edge.collect.poller import default_session
from edge.focas.client import MAX_SUBPACKETS
from edge.service.settings import machine_settings
from tests.unit.config.minimal import MINIMAL, parse, problems_of


@pytest.mark.parametrize("bad", ["a/b", "a#", "+", ""])
def test_machine_ids_follow_sparkplug_rules(bad: str) -> None:
    (problem,) = problems_of(MINIMAL.replace("id: m1", f"id: '{bad}'"))
    assert problem.startswith("machines[0].id: ")


def test_history_depth_clamped_with_a_warning() -> None:
    config = parse(MINIMAL + "alarms: {mode: ActivePlusHistory, history_depth: 400}\n")
    assert config.alarms.history_depth == 250
    depth_warnings = [w for w in config.warnings if "history_depth" in w]
    assert len(depth_warnings) == 1
    assert depth_warnings[0].startswith("alarms.history_depth: 400 is outside 1..250")
    low = parse(MINIMAL.replace("host: 10.0.0.1", "host: 10.0.0.1\n    alarms: {history_depth: 0}"))
    assert low.alarms_for(low.machines[0]).history_depth == 1
    assert low.warnings[0].startswith("machines[0].alarms.history_depth: 0")


def test_packed_transport_addresses() -> None:
    config = parse("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, transport: packed, address: "unix:/run/x.sock"}
          - {id: b, transport: packed, address: "tcp:10.0.0.2:9000"}
          - {id: c, transport: packed, host: 10.0.0.3, port: 9001}
    """)
    assert [m.endpoint for m in config.machines] == ["unix:/run/x.sock", "tcp:10.0.0.2:9000", "tcp:10.0.0.3:9001"]
    problems = problems_of("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, transport: packed, address: "udp:x"}
          - {id: b, address: "tcp:h:1"}
          - {id: c}
          - {id: d, transport: serial, host: h}
    """)
    assert any(p.startswith("machines[0].address: expected tcp:HOST:PORT or unix:/PATH") for p in problems)
    assert "machines[1].address: only for transport packed; the focas transport uses host and port (line 5)" in problems
    assert "machines[2].host: required (line 6)" in problems
    assert any(p.startswith("machines[3].transport: ") for p in problems)


def test_max_subpackets_reaches_the_client_and_is_checked() -> None:
    config = parse("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, host: h}
          - {id: b, host: h, max_subpackets: 64}
    """)
    clients = [default_session(machine_settings(config, m)) for m in config.machines]
    assert [c.max_subpackets for c in clients] == [MAX_SUBPACKETS, 64]  # type: ignore[attr-defined]
    problems = problems_of("""
        mqtt: {host: b, formats: [json]}
        machines:
          - {id: a, host: h, max_subpackets: 1}
          - {id: b, host: h, max_subpackets: 500}
          - {id: c, transport: packed, address: "tcp:h:1", max_subpackets: 8}
    """)
    assert any(p.startswith("machines[0].max_subpackets: ") and "2" in p for p in problems), problems
    assert any(p.startswith("machines[1].max_subpackets: ") and "128" in p for p in problems), problems
    assert ("machines[2].max_subpackets: only for transport focas (the packed surface has no subpackets) (line 6)"
            in problems), problems
