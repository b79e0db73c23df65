"""Hooks for ``schemathesis run`` with a viewer's, an operator's or a metrics token (test_openapi_roles.py):
the joined rules of schemathesis_hooks.py, and a check named ``role_table``: every answer agrees with the
route-roles table (tests/backend/api/test_route_roles.py). An operation above the token's role is refused with
403 whatever the request holds (before its path, query or body is looked at: a viewer learns nothing from an
admin route, not even whether a robot exists); one within it is never refused for the role (401 or 403)."""

from __future__ import annotations

import os
from typing import Any

import schemathesis

from backend.core.security import Role
from tests.backend.api.schemathesis_hooks import before_call  # noqa: F401  (registers the hook)
from tests.backend.api.test_route_roles import EXPECTED

#: the token's role, from the test that runs schemathesis
TOKEN_ROLE = Role.parse(os.environ.get("FLEET_SCHEMATHESIS_ROLE", "viewer"))


@schemathesis.check
def role_table(ctx: Any, response: Any, case: Any) -> bool | None:
    key = (case.operation.method.upper(), case.operation.path)
    needs = EXPECTED.get(key)
    if needs is None:
        raise AssertionError(f"{key[0]} {key[1]} is not in the route-roles table")
    status = response.status_code
    if isinstance(needs, Role) and needs > TOKEN_ROLE:
        if status != 403:
            raise AssertionError(f"a {TOKEN_ROLE.label} token got {status} from a {needs.label} route (403 expected)")
    elif _refused_for_the_token(status, response):
        raise AssertionError(f"a {TOKEN_ROLE.label} token was refused ({status}) by a route it may call")
    return None


def _refused_for_the_token(status: int, response: Any) -> bool:
    """A refusal of the credential or its role (not a route's own 401/403, such as a wrong password at login)."""
    if status not in (401, 403):
        return False
    try:
        body = response.json()
    except Exception:
        return True
    detail = str(body.get("detail", "")) if isinstance(body, dict) else ""
    return (status == 401 and body.get("code") == "unauthorized") or (status == 403 and "role required" in detail)
