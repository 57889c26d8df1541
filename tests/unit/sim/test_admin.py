"""The admin endpoint's routes, in process."""

from __future__ import annotations

import pytest

from edge.sim.admin import AdminServer, HttpError
from edge.sim.fleet import Fleet, MachineSpec


def test_admin_routes_in_process() -> None:
    fleet = Fleet([MachineSpec(profile="30i"), MachineSpec(profile="16i")], base_port=0)
    admin = AdminServer(fleet)
    listing = admin.handle("GET", "/machines", {})
    assert [m["profile"] for m in listing] == ["30i", "16i"]
    admin.handle("POST", "/machines/1/state", {"macros": {"501": 4.5}, "param_write_enable": True,
                                               "params": {"1815/2": 1}, "pmc": {"R10": [7, 8]},
                                               "raise_alarm": {"number": 1004, "type": "EX"}})
    state = fleet[1].state
    assert state.read_macro(501) == 4.5 and state.param_write_enabled
    assert state.read_param_value(1815, 2) == 1 and state.read_pmc_bytes("R", 10, 11) == b"\x07\x08"
    assert [a.number for a in state.active_alarms()] == [1004]
    result = admin.handle("POST", "/machines/0/faults", {"hang": 1, "ew": {"read_macros": 6}})
    assert result["faults"]["hang"] == 1 and fleet[0].faults.ew_for(0x15, "read_macros") == 6
    writes = admin.handle("GET", "/machines/1/writes", {})
    assert writes[0]["target"] == "macro:501" and writes[0]["protocol"] == "admin"
    with pytest.raises(HttpError) as missing:
        admin.handle("GET", "/machines/5", {})
    assert missing.value.status == 404
    with pytest.raises(ValueError):
        admin.handle("POST", "/machines/0/state", {"colour": "red"})


def test_feed_hold_holds_the_status_word_until_released() -> None:
    """`feed_hold` drives run HOLD (a test or the status page's scenario needs a machine in feed hold)."""
    fleet = Fleet([MachineSpec(profile="30i")], base_port=0)
    admin = AdminServer(fleet)
    state = fleet[0].state
    admin.handle("POST", "/machines/0/state", {"feed_hold": True})
    held = state.status()
    assert (held.run, held.motion) == (2, 0)
    admin.handle("POST", "/machines/0/state", {"feed_hold": False})
    assert state.status().run in (0, 3)  # back to the cycle: reset between parts, STaRT while cutting
