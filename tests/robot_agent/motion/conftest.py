"""Motion tests: real Mosquitto, real simulated agents (disturbances on), the test playing the server."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.support.motion import FakeServer
from tests.support.procs import Broker


@pytest.fixture
def fake_server(broker: Broker) -> Iterator[FakeServer]:
    s = FakeServer(broker.host, broker.port)
    try:
        yield s
    finally:
        s.close()
