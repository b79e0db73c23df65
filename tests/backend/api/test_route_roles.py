"""Deny by default: every route declares who may call it, and the declarations are the intended ones.

A new route without a role makes ``create_app`` fail (so the server does not start) and this table fail
until someone decides its role here, on purpose.
"""

from __future__ import annotations

import pytest
from fastapi import APIRouter

from backend.api.deps import ROLE_ATTR, check_route_roles, iter_api_routes, route_role, route_roles
from backend.core.config import Settings
from backend.core.security import Role
from backend.main import create_app

P, M, V, OP, A = "public", Role.METRICS, Role.VIEWER, Role.OPERATOR, Role.ADMIN

EXPECTED: dict[tuple[str, str], Role | str] = {
    # public: the UI shell (no data), login, logout (ends only the caller's own session), minimal health
    ("GET", "/"): P,
    ("GET", "/login"): P,
    ("GET", "/robots/{robot_id}"): P,
    ("GET", "/history"): P,
    ("GET", "/users"): P,  # the page shell; the data behind it is admin-only
    ("GET", "/audit"): P,  # the same
    ("GET", "/runs"): P,
    ("GET", "/runs/{run_id}"): P,
    ("GET", "/missions"): P,
    ("GET", "/missions/{mission_id}"): P,
    ("GET", "/docs"): P,
    ("GET", "/api/health"): P,
    ("POST", "/api/auth/login"): P,
    ("POST", "/api/auth/logout"): P,
    # a robot's single-use enrolment token is the credential (issue 29 #3): used once, expiring, rate-limited
    ("POST", "/api/enrol"): P,
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
    # a metrics token (Prometheus) may scrape and do nothing else; every other role may scrape too
    ("GET", "/metrics"): M,
    ("GET", "/api/estop"): V,
    ("GET", "/api/site"): V,
    ("GET", "/api/site/versions"): V,
    ("PUT", "/api/site"): A,  # the geofence every robot obeys
    ("DELETE", "/api/site"): A,
    ("GET", "/api/units"): V,
    ("WS", "/ws"): V,
    ("WS", "/ws/camera/{robot_id}"): V,
    # an off-board controller drives its robot over this socket (same rules as POST .../commands)
    ("WS", "/ws/control/{robot_id}"): OP,
    # safety: anyone logged in may press the e-stop; releasing it lets robots move, so operator
    ("POST", "/api/estop"): V,
    ("POST", "/api/estop/release"): OP,
    # the same for one robot's stop latch (hold): anyone holds it, an operator releases it
    ("PUT", "/api/robots/{robot_id}/hold"): V,
    ("DELETE", "/api/robots/{robot_id}/hold"): OP,
    # which command topic an old-framework robot listens on decides what a drive moves: admin
    ("PUT", "/api/robots/{robot_id}/legacy-addressing"): A,
    # which robots may speak on the old framework's anonymous topics: admin
    ("PUT", "/api/robots/{robot_id}/legacy"): A,
    ("DELETE", "/api/robots/{robot_id}/legacy"): A,
    # operator: drive, and take, release, ask for or grant a robot's control lease (admins take it over)
    ("POST", "/api/robots/{robot_id}/commands"): OP,
    ("GET", "/api/robots/{robot_id}/lease"): V,
    ("POST", "/api/robots/{robot_id}/lease"): OP,
    ("DELETE", "/api/robots/{robot_id}/lease"): OP,
    ("POST", "/api/robots/{robot_id}/lease/request"): OP,
    ("POST", "/api/robots/{robot_id}/lease/grant"): OP,
    # admin: the audit trail
    ("GET", "/api/audit"): A,
    # experiment runs: everyone finds, reads and exports them; an operator starts, stops, edits and marks;
    # deleting one is an admin's (audited)
    ("GET", "/api/runs"): V,
    ("POST", "/api/runs"): OP,
    ("GET", "/api/runs/{run_id}"): V,
    ("PATCH", "/api/runs/{run_id}"): OP,
    ("DELETE", "/api/runs/{run_id}"): A,
    ("POST", "/api/runs/{run_id}/stop"): OP,
    ("GET", "/api/runs/{run_id}/markers"): V,
    ("POST", "/api/runs/{run_id}/markers"): OP,
    ("GET", "/api/runs/{run_id}/export"): V,
    ("GET", "/api/runs/{run_id}/frames"): V,
    ("GET", "/api/runs/{run_id}/frames/times"): V,
    # missions: everyone reads them, an operator creates and runs them
    ("GET", "/api/missions"): V,
    ("GET", "/api/missions/{mission_id}"): V,
    ("GET", "/api/missions/{mission_id}/coverage"): V,
    ("POST", "/api/missions"): OP,
    ("POST", "/api/missions/{mission_id}/start"): OP,
    ("POST", "/api/missions/{mission_id}/pause"): OP,
    ("POST", "/api/missions/{mission_id}/resume"): OP,
    ("POST", "/api/missions/{mission_id}/abort"): OP,
    ("POST", "/api/missions/{mission_id}/rehearsal"): OP,
    # alarms: everyone sees them, an operator acknowledges, an admin sets the rules and overrides a battery
    ("GET", "/api/alarms"): V,
    ("POST", "/api/alarms/{alarm_id}/ack"): OP,
    ("GET", "/api/alarm-rules"): V,
    ("PUT", "/api/alarm-rules"): A,
    ("POST", "/api/robots/{robot_id}/battery-override"): A,
    # admin: users and tokens, forgetting a robot
    ("DELETE", "/api/robots/{robot_id}"): A,
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


def test_the_role_is_checked_before_anything_else():
    """A route's strictest role is a dependency of its router or decorator, before any of its parameters: a
    viewer calling an admin route about an unknown robot gets 403, not a 404 that says which robots exist
    (tests/backend/api/test_openapi_roles.py sends every operation with each role)."""
    late = []
    for path, methods, dependant in iter_api_routes(create_app(Settings())):
        strictest = route_role(dependant)
        for dep in dependant.dependencies:
            mark = getattr(dep.call, ROLE_ATTR, None)
            if mark == strictest:
                break
            if mark is None:
                late.extend(f"{m} {path}" for m in methods)
                break
    assert late == []


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
