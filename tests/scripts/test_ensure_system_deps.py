"""scripts/ensure-system-deps.sh: installs only what is missing, runs `apt-get update` only then, never
prompts. The machine's own apt is not touched: `dpkg-query`, `apt-get`, `id` and `sudo` are stand-ins on
PATH that record how they were called."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "ensure-system-deps.sh"
PACKAGES = ["mosquitto", "mosquitto-clients", "chromium", "fonts-liberation", "fonts-dejavu-core", "docker-compose"]


def _stubs(tmp: Path, missing: set[str], uid: int = 0, sudo: bool = False) -> Path:
    bin_ = tmp / "bin"
    bin_.mkdir()
    log = tmp / "calls.log"
    stubs = {
        "dpkg-query": "for a; do pkg=$a; done\n"
        f'case " {" ".join(sorted(missing))} " in *" $pkg "*) exit 1;; esac\n'
        "printf 'install ok installed'\n",
        "apt-get": f'echo "apt-get $* DEBIAN_FRONTEND=${{DEBIAN_FRONTEND:-}} uid=$FAKE_UID" >> {log}\n',
        "id": f"echo {uid}\n",
    }
    if sudo:
        stubs["sudo"] = f'echo "sudo $*" >> {log}\nFAKE_UID=0 exec "$@"\n'
    for name, body in stubs.items():
        path = bin_ / name
        path.write_text("#!/usr/bin/env bash\n" + body)
        path.chmod(0o755)
    return bin_


def _run(tmp: Path, bin_: Path, *args: str, uid: int = 0) -> tuple[subprocess.CompletedProcess[str], list[str]]:
    env = dict(os.environ, PATH=f"{bin_}:{os.environ['PATH']}", FAKE_UID=str(uid))
    env.pop("DEBIAN_FRONTEND", None)
    r = subprocess.run(
        ["bash", str(SCRIPT), *args], capture_output=True, text=True, env=env, timeout=60, stdin=subprocess.DEVNULL
    )
    log = tmp / "calls.log"
    return r, (log.read_text().splitlines() if log.exists() else [])


def test_nothing_missing_means_no_apt_at_all(tmp_path: Path) -> None:
    r, calls = _run(tmp_path, _stubs(tmp_path, set()))
    assert r.returncode == 0, r.stderr
    assert calls == []


def test_only_the_missing_packages_are_installed_without_prompts(tmp_path: Path) -> None:
    r, calls = _run(tmp_path, _stubs(tmp_path, {"chromium", "docker-compose"}))
    assert r.returncode == 0, r.stderr
    assert calls == [
        "apt-get update -qq DEBIAN_FRONTEND=noninteractive uid=0",
        "apt-get install -y -qq --no-install-recommends chromium docker-compose DEBIAN_FRONTEND=noninteractive uid=0",
    ]


def test_check_mode_reports_and_installs_nothing(tmp_path: Path) -> None:
    r, calls = _run(tmp_path, _stubs(tmp_path, {"mosquitto"}), "--check")
    assert r.returncode == 1 and "mosquitto" in r.stdout
    assert calls == []


def test_not_root_uses_sudo_when_there_is_one(tmp_path: Path) -> None:
    r, calls = _run(tmp_path, _stubs(tmp_path, {"mosquitto"}, uid=1000, sudo=True), uid=1000)
    assert r.returncode == 0, r.stderr
    assert calls[0].startswith("sudo env DEBIAN_FRONTEND=noninteractive apt-get update")
    assert "apt-get install -y -qq --no-install-recommends mosquitto DEBIAN_FRONTEND=noninteractive uid=0" in calls


def test_not_root_without_sudo_fails_with_a_clear_message(tmp_path: Path) -> None:
    bin_ = _stubs(tmp_path, {"mosquitto"}, uid=1000)
    for tool in ("bash", "grep", "env"):  # a PATH with what the script needs and no sudo
        real = shutil.which(tool)
        assert real is not None
        (bin_ / tool).symlink_to(real)
    (bin_ / "python3").symlink_to(os.path.realpath(sys.executable))
    r = subprocess.run(
        ["/bin/bash", str(SCRIPT)],
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": str(bin_), "FAKE_UID": "1000"},
        stdin=subprocess.DEVNULL,
    )
    assert r.returncode == 1, r.stdout + r.stderr
    assert "need root (or sudo) to install: mosquitto" in r.stderr
    assert not (tmp_path / "calls.log").exists()


def test_this_machine_has_everything() -> None:
    """`make test` ran the script before the suite: nothing may be missing now."""
    r = subprocess.run(["bash", str(SCRIPT), "--check"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
