"""The command line's own tests start the real ``fleet-server`` executable, never a fork of the zygote."""

from __future__ import annotations

import pytest

from tests.support.procs import ServerProcess


@pytest.fixture(autouse=True)
def real_executable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ServerProcess, "zygote", None)
