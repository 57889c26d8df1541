"""The control profiles: what each series says about itself."""

from __future__ import annotations

import pytest

from edge.sim.profiles import PROFILES, get_profile


def test_profiles() -> None:
    assert set(PROFILES) >= {"0i-F", "16i", "30i", "31i"}
    assert get_profile("16i").sysinfo.max_axis == 8 and get_profile("31i").sysinfo.max_axis == 32
    assert get_profile("16I") is PROFILES["16i"] and get_profile("31i-B") is PROFILES["31i"]
    assert {p.response_version for p in PROFILES.values()} == {2, 3, 4}
    with pytest.raises(ValueError, match="expected one of"):
        get_profile("18i")
