"""The simulated machine's parameters and diagnoses: the write-enable switch, EW codes, record forms."""

from __future__ import annotations

import pytest

from edge.focas.errors import (
    EW_ATTRIB,
    EW_DATA,
    EW_NUMBER,
    EW_PASSWD,
    AccessDenied,
    CncError,
    OutOfRange,
)
from tests.unit.sim.helpers import machine


def test_parameter_write_needs_the_enable_switch() -> None:
    state, _ = machine()
    with pytest.raises(AccessDenied) as caught:
        state.write_param(6711, 0, 5)
    assert caught.value.code == EW_PASSWD
    state.set_param_write_enable(True)
    state.write_param(6711, 0, 5)
    state.write_param(1815, 2, 0b0011_0001)
    assert state.part_count == 5
    assert state.read_params(1815, 1815, 2)[0].values == (0b0011_0001,)
    assert [(w.target, w.old, w.new) for w in state.writes("param:")] == [
        ("param:6711", 0, 5), ("param:1815/2", 0b0011_0000, 0b0011_0001)]


@pytest.mark.parametrize(("number", "axis", "value", "code"), [
    (9999, 0, 1, EW_NUMBER),
    (1815, 0, 1, EW_ATTRIB),  # per-axis needs an axis
    (1815, 9, 1, EW_ATTRIB),
    (6711, 1, 1, EW_ATTRIB),  # not per axis
    (1815, 1, 256, EW_DATA),  # a bit parameter holds one byte
    (1825, 1, 40000, EW_DATA),  # word
    (6711, 0, 1.5, EW_DATA),  # 2-word is an integer
])
def test_parameter_write_errors(number: int, axis: int, value: float, code: int) -> None:
    state, _ = machine()
    state.set_param_write_enable(True)
    with pytest.raises(CncError) as caught:
        state.write_param(number, axis, value)
    assert caught.value.code == code
    assert state.write_log == []


def test_every_parameter_type_is_present() -> None:
    for name in ("16i", "30i"):
        state, _ = machine(name)
        types = {r.type for r in state.read_params(0, 9999, -1)}
        expected = {0, 1, 2, 3, 4} if state.profile.wide_records else {0, 1, 2, 3}
        assert types == expected, name


def test_parameter_record_axis_forms() -> None:
    state, _ = machine("16i")
    (all_axes,) = state.read_params(1020, 1020, -1)
    assert all_axes.axis == -1 and all_axes.values == tuple(ord(a) for a in "XYZB")
    (one,) = state.read_params(1020, 1020, 3)
    assert (one.axis, one.values) == (3, (ord("Z"),))
    (whole,) = state.read_params(3281, 3281, 2)
    assert (whole.axis, whole.values) == (0, (0,))
    with pytest.raises(OutOfRange):
        state.read_params(1020, 1020, 5)
    with pytest.raises(OutOfRange) as none:
        state.read_params(2, 19)
    assert none.value.code == EW_NUMBER


def test_diagnoses_follow_the_cycle() -> None:
    state, clock = machine()
    clock.tick(2.3)
    records = {r.number: r for r in state.read_diag(980, 982, -1)}
    machine_pos = state.positions("machine")
    assert list(records[980].values) == [int(v * 1000) for v in machine_pos]
    clock.tick(10.0)
    (load,) = state.read_diag(410, 410)
    assert load.value == 0
