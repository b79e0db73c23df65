"""``make test``'s pytest part: every collected test, in two lanes, each writing a JUnit report.

1. **parallel**: every test not marked ``realtime``, on ``--workers`` pytest-xdist workers (``--dist
   loadgroup``: a module whose tests share a module-scoped fixture stays on one worker). Most of these tests
   wait for robots to move, so several run beside each other on two cores.
2. **realtime**: the tests marked ``realtime`` (a safety bound measured in wall-clock time: deadman, e-stop,
   link cut, watchdogs, a killed server), one at a time, after the first lane, on a quiet machine.

Both lanes always run; the exit status is the worse of the two. Extra arguments go to both lanes (use ``-k``
to pick tests: a lane in which nothing is selected is not a failure as long as the other ran something).
docs/testing.md describes the lanes; ``make test-report`` reads the reports.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "test-results"
NO_TESTS = 5  # pytest's exit status when nothing was selected


def lanes(workers: int, browser_workers: int) -> list[tuple[str, list[str]]]:
    return [
        ("parallel", ["-m", "not realtime and not browser", "-n", str(workers), "--dist", "loadgroup"]),
        ("browser", ["-m", "browser and not realtime", "-n", str(browser_workers), "--dist", "loadgroup"]),
        ("realtime", ["-m", "realtime", "-n", "0"]),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=int(os.environ.get("FLEET_TEST_WORKERS", "3")))
    ap.add_argument("--browser-workers", type=int, default=int(os.environ.get("FLEET_TEST_BROWSER_WORKERS", "1")))
    args, pytest_args = ap.parse_known_args(argv)
    RESULTS.mkdir(exist_ok=True)
    for old in RESULTS.glob("junit-*.xml"):
        old.unlink()
    codes: dict[str, int] = {}
    started = time.monotonic()
    for name, lane_args in lanes(args.workers, args.browser_workers):
        print(f"\n=== lane {name}: pytest {' '.join(lane_args)} ===", flush=True)
        t0 = time.monotonic()
        cmd = [sys.executable, "-m", "pytest", "-q", *lane_args, f"--junitxml={RESULTS / f'junit-{name}.xml'}"]
        codes[name] = subprocess.call([*cmd, *pytest_args], cwd=ROOT)
        print(f"=== lane {name}: exit {codes[name]} after {(time.monotonic() - t0) / 60:.1f} min ===", flush=True)
    ran = [c for c in codes.values() if c != NO_TESTS]
    status = max(ran) if ran else NO_TESTS
    print(f"\n=== both lanes: {(time.monotonic() - started) / 60:.1f} min; exit {status} ===", flush=True)
    subprocess.call([sys.executable, str(ROOT / "scripts" / "test_report.py"), "--slowest", "10"], cwd=ROOT)
    print(closing_line())
    return status


def closing_line() -> str:
    """Both lanes' counts as one plain ``N passed, N failed, N skipped`` line, the last the run prints."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from test_report import read_lane

    outcomes = [c.outcome for p in sorted(RESULTS.glob("junit-*.xml")) for c in read_lane(p).cases]
    failed = sum(o in ("failed", "error") for o in outcomes)
    return f"total: {outcomes.count('passed')} passed, {failed} failed, {outcomes.count('skipped')} skipped"


if __name__ == "__main__":
    sys.exit(main())
