"""Security suite fixtures: clients holding tokens of a given role."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import httpx
import pytest

from tests.support.procs import ServerProcess


def new_token(server: ServerProcess, role: str, name: str | None = None) -> str:
    with server.client() as c:
        r = c.post("/api/tokens", json={"name": name or f"test-{role}", "role": role})
        assert r.status_code == 201, r.text
        return r.json()["token"]  # type: ignore[no-any-return]


@pytest.fixture
def role_client(server: ServerProcess) -> Iterator[Callable[[str], httpx.Client]]:
    """``role_client("viewer")``: an HTTP client with a fresh API token of that role."""
    clients: list[httpx.Client] = []

    def _make(role: str) -> httpx.Client:
        c = server.client(new_token(server, role))
        clients.append(c)
        return c

    try:
        yield _make
    finally:
        for c in clients:
            c.close()
