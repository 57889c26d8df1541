"""The native server's reference answers (answer_subpacket), pure: record forms, unknown commands and
paths, forced codes, the PMC write limit on the wire, an answer for any request."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from edge.focas import functions as fn
from edge.focas.errors import (
    EW_FUNC,
    EW_LENGTH,
    EW_PATH,
)
from edge.focas.frame import RequestSubpacket
from edge.sim.faults import FaultPlan
from edge.sim.native_handlers import answer_subpacket
from edge.sim.state import MachineState
from tests.unit.sim.helpers import T0, machine


@pytest.mark.parametrize("name", ["16i", "30i", "0i-F"])
def test_only_the_profiles_record_form_answers(name: str) -> None:
    state, _ = machine(name)
    wide = state.profile.wide_records
    for function in (fn.READ_PARAMS_4, fn.READ_PARAMS_8, fn.READ_DIAG_4, fn.READ_DIAG_8):
        first = 6711 if "params" in function.name else 980
        answer = answer_subpacket(state, function.request(first, first, 0))
        answers_here = (function.command in (0x8D, 0x93)) == wide
        assert answer.rc == (0 if answers_here else EW_FUNC), (name, hex(function.command))


def test_unknown_command_path_and_forced_codes() -> None:
    state, _ = machine()
    assert answer_subpacket(state, RequestSubpacket(1, 0x7777)).rc == EW_FUNC
    assert answer_subpacket(state, fn.STATINFO.request(path=2)).rc == EW_PATH
    faults = FaultPlan(ew={"statinfo": 15, 0x18: 6})
    assert answer_subpacket(state, fn.STATINFO.request(), faults).rc == 15
    assert answer_subpacket(state, fn.SYSINFO.request(), faults).rc == 6
    assert answer_subpacket(state, fn.READ_MACROS.request(500, 500), faults).rc == 0


def test_pmc_write_over_32_bytes_is_ew_length_on_the_wire() -> None:
    state, _ = machine()
    answer = answer_subpacket(state, fn.write_pmc_request("R", 0, bytes(33)))
    assert answer.rc == EW_LENGTH
    assert answer_subpacket(state, fn.write_pmc_request("R", 0, bytes(32))).rc == 0


@given(st.integers(-(2**31), 2**31 - 1), st.integers(-(2**31), 2**31 - 1), st.integers(-(2**15), 2**15 - 1),
       st.integers(0, 0xFFFF))
def test_property_any_request_gets_an_answer(first: int, last: int, axis: int, command: int) -> None:
    state = MachineState("30i", time_source=lambda: T0)
    answer = answer_subpacket(state, RequestSubpacket(1, command, (first, last, axis, 0, 0)))
    assert (answer.cls, answer.path, answer.command) == (1, 1, command)
    assert answer.rc >= 0 and (answer.rc == 0 or answer.payload == b"")
