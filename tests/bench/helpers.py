"""Running bench/run_all.py on small settings, shared by the benchmark smoke tests."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def run_all_quick(tmp_path: Path, *names: str, timeout: float = 300) -> dict[str, dict[str, Any]]:
    """``run_all.py --quick --only NAME...``: each benchmark's result by name (the run must succeed)."""
    out = tmp_path / "results.json"
    only = [arg for name in names for arg in ("--only", name)]
    proc = subprocess.run(
        [sys.executable, "bench/run_all.py", "--quick", *only, "--json", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return {r["bench"]: r for r in json.loads(out.read_text())}


def run_bench(script: str, *args: str, timeout: float = 300) -> dict[str, Any]:
    """``bench/SCRIPT ARGS...`` on its own: the last ``RESULT`` line it printed (the run must succeed)."""
    proc = subprocess.run(
        [sys.executable, f"bench/{script}", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    return json.loads(lines[-1][len("RESULT ") :])  # type: ignore[no-any-return]
