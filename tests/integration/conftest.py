from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from tests.helpers import Mosquitto
from tests.integration.mqtt_observer import Observer


@pytest.fixture
async def observer(mosquitto: Mosquitto) -> AsyncIterator[Observer]:
    """An MQTT client recording everything under spBv1.0/# and focas/# on the test's broker."""
    obs = Observer(mosquitto)
    yield obs
    obs.close()
