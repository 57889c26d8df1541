from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

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


@pytest.fixture
def open_dir() -> Iterator[Path]:
    """A directory any user can enter (pytest's tmp_path is 0700, which would hide everything in it from the
    other user a test runs a command as), removed afterwards."""
    path = Path(tempfile.mkdtemp(prefix="focas-edge-test-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path)
