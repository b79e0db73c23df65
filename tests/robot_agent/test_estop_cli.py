"""`fleet-agent estop` says clearly what went wrong: bad arguments exit 2, a broker it cannot reach exits 1
and says the e-stop is NOT engaged (the real CLI process). A broker refusing the login, and the ACL dropping
the publish: tests/deploy/test_acl_safety.py."""

from __future__ import annotations

import subprocess

from tests.support.procs import VENV_BIN, base_env, free_port


def _run(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(VENV_BIN / "fleet-agent"), "estop", *args], env=base_env(**env), capture_output=True, text=True, timeout=60
    )


def test_bad_arguments_and_unreachable_brokers_are_reported() -> None:
    bad = _run("--broker", "http://base:1883")
    assert bad.returncode == 2 and "fleet-agent estop:" in bad.stderr, bad.stderr
    missing = _run("--password-file", "/nonexistent/estop-password")
    assert missing.returncode == 2 and "/nonexistent/estop-password" in missing.stderr
    nobody = _run("--broker", f"mqtt://127.0.0.1:{free_port()}", "--timeout", "2")
    assert nobody.returncode == 1 and "e-stop NOT engaged" in nobody.stderr and "cannot reach" in nobody.stderr
    assert "no password given" in nobody.stderr
