"""Fixtures the integration tests share."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from tests.helpers import Mosquitto
from tests.integration.mqtt_observer import Observer
from tests.integration.tcp_relay import TcpRelay


@pytest.fixture
async def observer(mosquitto: Mosquitto) -> AsyncIterator[Observer]:
    """A subscriber to everything on the test's broker, closed after the test."""
    obs = Observer(mosquitto)
    yield obs
    obs.close()


@pytest.fixture
async def relay(mosquitto: Mosquitto) -> AsyncIterator[TcpRelay]:
    """A TCP relay to the test's broker: the daemon's broker address, which a drill can shape."""
    r = TcpRelay(mosquitto.host, mosquitto.port)
    await r.start()
    yield r
    await r.close()
