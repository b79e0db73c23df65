"""The dashboard's rooms (issue 30): every folder of frontend/js has a rule in dependency-cruiser's config, and
the check `make lint` runs refuses an import a rule forbids (proved on a copy with one added)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
JS = ROOT / "frontend" / "js"
CONFIG = ROOT / "tools" / "depcruise" / "dependency-cruiser.cjs"
DEPCRUISE = ROOT / "tools" / "depcruise" / "node_modules" / ".bin" / "depcruise"


def _rooms() -> dict[str, list[str]]:
    block = CONFIG.read_text().split("const ROOMS = {", 1)[1].split("};", 1)[0]
    return {m[1]: re.findall(r'"(\w+)"', m[2]) for m in re.finditer(r"^\s+(\w+): \[([^\]]*)\]", block, re.M)}


def _cruise(root: Path) -> subprocess.CompletedProcess[str]:
    if not DEPCRUISE.exists():
        pytest.fail("dependency-cruiser missing: `make test` and `make lint` install it (tools/depcruise)")
    return subprocess.run(
        [str(DEPCRUISE), "--config", str(CONFIG), "--output-type", "err", "frontend/js"],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_every_folder_of_the_dashboard_has_its_rule() -> None:
    folders = sorted(p.name for p in JS.iterdir() if p.is_dir())
    rooms = _rooms()
    assert folders == sorted(rooms), (folders, sorted(rooms))
    for room, allowed in rooms.items():
        assert room in allowed and "core" in allowed and set(allowed) <= set(rooms), (room, allowed)
    loose = sorted(p.name for p in JS.glob("*.js"))
    assert loose == ["apidocs.js", "app.js", "login.js"], loose  # only the pages' entry points at the top


def test_the_rules_pass_and_refuse_a_forbidden_import(tmp_path: Path) -> None:
    assert _cruise(ROOT).returncode == 0
    copy = tmp_path / "frontend" / "js"
    shutil.copytree(JS, copy)
    util = copy / "core" / "util.js"
    forbidden = '\nimport { FleetMap } from "../map/fleetmap.js";\nexport const map = FleetMap;\n'
    util.write_text(util.read_text() + forbidden)
    done = _cruise(tmp_path)
    assert done.returncode != 0
    assert "core-imports-only-core: frontend/js/core/util.js → frontend/js/map/fleetmap.js" in done.stdout, done.stdout
