"""Schemathesis with authentication on, below admin (issue 29): with a metrics token, a viewer's and an
operator's, each operation of the OpenAPI once (positive and negative data), every answer checked against the
route-roles table (``role_table`` in schemathesis_roles.py) and for 5xx. The full fuzz with an admin token and
every check is test_openapi_all_checks.py."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from tests.backend.api.test_openapi_all_checks import fresh  # noqa: F401  (a fresh server of this module's own)
from tests.support.procs import VENV_BIN, ServerProcess

HOOKS = "tests.backend.api.schemathesis_roles"
REPO = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("role", ["metrics", "viewer", "operator"])
def test_each_operation_answers_each_role_as_the_route_roles_table_says(
    fresh: ServerProcess,  # noqa: F811
    tmp_path: Path,
    role: str,
) -> None:
    with fresh.client() as admin:
        made = admin.post("/api/tokens", json={"name": f"schemathesis-{role}", "role": role})
        assert made.status_code == 201, made.text
    done = subprocess.run(
        [
            str(VENV_BIN / "schemathesis"),
            "run",
            f"{fresh.base_url}/openapi.json",
            "--checks",
            "not_a_server_error,role_table",
            "--header",
            f"Authorization: Bearer {made.json()['token']}",
            "--max-examples",
            "1",
            "--phases",
            "examples,fuzzing",
            "--no-color",
            *(["--seed", os.environ["FLEET_SCHEMATHESIS_SEED"]] if "FLEET_SCHEMATHESIS_SEED" in os.environ else []),
        ],
        cwd=tmp_path,
        env={**os.environ, "SCHEMATHESIS_HOOKS": HOOKS, "FLEET_SCHEMATHESIS_ROLE": role, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=600,
    )
    report = done.stdout + done.stderr
    failures = report.find("FAILURES")
    assert done.returncode == 0, report[failures : failures + 8000] if failures >= 0 else report[-12000:]
