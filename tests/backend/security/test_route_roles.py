"""Deny by default: every route declares who may call it, and the declarations are the intended ones.

A new route without a role makes ``create_app`` fail (so the server does not start) and this table fail
until someone decides its role here, on purpose.
"""

from __future__ import annotations

import pytest
from fastapi import APIRouter

from backend.api.deps import check_route_roles, route_roles
from backend.core.config import Settings
from backend.core.security import Role
from backend.main import create_app

P, V, OP, A = "public", Role.VIEWER, Role.OPERATOR, Role.ADMIN

EXPECTED: dict[tuple[str, str], Role | str] = {
    # public: the UI shell (no data), login, logout (ends only the caller's own session), minimal health
    ("GET", "/"): P,
    ("GET", "/login"): P,
    ("GET", "/robots/{robot_id}"): P,
    ("GET", "/history"): P,
    ("GET", "/docs"): P,
    ("GET", "/api/health"): P,
    ("POST", "/api/auth/login"): P,
    ("POST", "/api/auth/logout"): P,
    # viewer: read everything, live and historic
    ("GET", "/api/auth/me"): V,
    ("GET", "/api/robots"): V,
    ("GET", "/api/robots/{robot_id}"): V,
    ("GET", "/api/robots/{robot_id}/streams"): V,
    ("GET", "/api/robots/{robot_id}/telemetry"): V,
    ("GET", "/api/telemetry"): V,
    ("GET", "/api/robots/{robot_id}/commands"): V,
    ("GET", "/api/robots/{robot_id}/camera/latest.jpg"): V,
    ("GET", "/api/commands/{command_id}"): V,
    ("GET", "/api/events"): V,
    ("GET", "/api/stats"): V,
    ("GET", "/metrics"): V,
    ("GET", "/api/estop"): V,
    ("WS", "/ws"): V,
    ("WS", "/ws/camera/{robot_id}"): V,
    # safety: anyone logged in may press the e-stop; releasing it lets robots move, so operator
    ("POST", "/api/estop"): V,
    ("POST", "/api/estop/release"): OP,
    # operator: drive
    ("POST", "/api/robots/{robot_id}/commands"): OP,
    # admin: users and tokens
    ("GET", "/api/tokens"): A,
    ("POST", "/api/tokens"): A,
    ("DELETE", "/api/tokens/{token_id}"): A,
    ("GET", "/api/users"): A,
    ("POST", "/api/users"): A,
    ("GET", "/api/users/{username}"): A,
    ("PATCH", "/api/users/{username}"): A,
    ("DELETE", "/api/users/{username}"): A,
}


def test_every_route_declares_the_intended_role():
    actual = route_roles(create_app(Settings()))
    assert None not in actual.values(), [k for k, v in actual.items() if v is None]
    assert set(actual) == set(EXPECTED), {
        "routes nobody decided a role for": sorted(set(actual) - set(EXPECTED)),
        "expected routes that are gone": sorted(set(EXPECTED) - set(actual)),
    }
    wrong = {k: (actual[k], EXPECTED[k]) for k in EXPECTED if actual[k] != EXPECTED[k]}
    assert not wrong, wrong


def test_undeclared_route_refuses_to_start():
    app = create_app(Settings())
    rogue = APIRouter()

    @rogue.get("/api/rogue")
    async def rogue_route() -> dict[str, str]:
        return {}

    app.include_router(rogue)
    with pytest.raises(RuntimeError, match="/api/rogue"):
        check_route_roles(app)


def test_openapi_documents_bearer_and_cookie_auth():
    spec = create_app(Settings()).openapi()
    schemes = spec["components"]["securitySchemes"]
    assert {s["type"] for s in schemes.values()} == {"http", "apiKey"}
    assert spec["paths"]["/api/robots"]["get"]["security"]
    assert "security" not in spec["paths"]["/api/auth/login"]["post"]
