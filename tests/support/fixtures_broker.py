"""A real mosquitto on 127.0.0.1:<free port> for each test that asks for one."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from scotti.daemon.tools.local_broker import Mosquitto


@pytest.fixture
def mosquitto() -> Iterator[Mosquitto]:
    """Running broker; ``.stop()`` / ``.start()`` restart it on the same port mid-test."""
    broker = Mosquitto()
    try:
        broker.start()
        yield broker
    finally:
        broker.close()
