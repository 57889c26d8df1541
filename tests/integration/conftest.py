"""Fixtures the integration tests share."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from tests.helpers import Mosquitto
from tests.integration.mqtt_observer import Observer


@pytest.fixture
async def observer(mosquitto: Mosquitto) -> AsyncIterator[Observer]:
    """A subscriber to everything on the test's broker, closed after the test."""
    obs = Observer(mosquitto)
    yield obs
    obs.close()
