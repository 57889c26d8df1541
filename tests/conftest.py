from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, settings

from tests.helpers import Mosquitto, mosquitto_binary

settings.register_profile("default", max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("fuzz", max_examples=20000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture
def mosquitto() -> Iterator[Mosquitto]:
    """A real mosquitto broker on a free port, started for this test and stopped after it."""
    binary = mosquitto_binary()
    if binary is None:
        pytest.skip("mosquitto is not installed (make test installs it where it can)")
    broker = Mosquitto(binary)
    broker.start()
    try:
        yield broker
    finally:
        broker.close()
