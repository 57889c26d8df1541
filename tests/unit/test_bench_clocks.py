"""The bench fleet's spread CNC clocks: distinct phases within the second, within the default max skew."""

from __future__ import annotations

from itertools import pairwise

from bench.clocks import cnc_clock_offset, device_clock_offset
from edge.config.machines import MachineConfig


def test_a_thousand_clocks_turn_their_seconds_at_distinct_moments() -> None:
    phases = sorted(cnc_clock_offset(i) % 1.0 for i in range(1000))
    gaps = [b - a for a, b in pairwise(phases)]
    assert max(gaps) < 0.005 and min(gaps) > 0.0  # no two flips together, no crowd anywhere in the second


def test_offsets_stay_where_the_gateway_keeps_cnc_time() -> None:
    max_skew = MachineConfig.model_fields["max_skew_s"].default
    assert all(abs(cnc_clock_offset(i)) < max_skew for i in range(1000))
    assert len({round(cnc_clock_offset(i)) for i in range(1000)}) > 60  # whole seconds differ too (hand-set)


def test_a_device_id_names_its_fleet_index() -> None:
    assert device_clock_offset("m001") == cnc_clock_offset(0)
    assert device_clock_offset("m1000") == cnc_clock_offset(999)
