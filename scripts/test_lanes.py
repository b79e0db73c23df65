"""``make test``'s pytest part: every collected test, in three lanes, each writing a JUnit report.

1. **parallel**: every test neither ``browser`` nor ``realtime``, on ``--workers`` pytest-xdist workers
   (``--dist loadgroup``: a module whose tests share a module-scoped fixture stays on one worker). Most of
   these tests wait for robots to move, so several run beside each other on two cores.
2. **browser**: the ``browser`` tests, on ``--browser-workers`` workers of their own (Playwright's sync API
   and ``asyncio.run`` do not share a process well).
3. **realtime**, last: the tests marked ``realtime`` (a safety bound measured in wall-clock
   time: deadman, e-stop, link cut, watchdogs, a killed server), one at a time, on a quiet machine.

With ``--lint`` (``make test``), ``make lint-checks`` runs niced beside the first lane and must end before the
next: a failed check fails the run. Every lane always runs; the exit status is the worst of them. Extra
arguments go to every lane (use ``-k`` to pick tests: a lane in which nothing is selected is not a failure
as long as another ran something).
docs/testing.md describes the lanes; ``make test-report`` reads the reports.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "test-results"
NO_TESTS = 5  # pytest's exit status when nothing was selected


#: lanes in stages: the lanes of a stage run side by side, a stage starts when the one before has ended.
#: One lane a stage: the parallel and browser lanes side by side took 12 min instead of 19, but kept both
#: cores at 95-100 % for ten minutes, and in two runs out of two 5 to 9 tests failed for it: robots' links
#: went silent and their missions failed, stale commands expired, formations drifted. That is the product
#: doing its job on a starved machine, so the lanes take turns (docs/testing.md, "Measured").
STAGES: tuple[tuple[str, ...], ...] = (("parallel",), ("browser",), ("realtime",))


def lanes(workers: int, browser_workers: int) -> dict[str, list[str]]:
    return {
        "parallel": ["-m", "not realtime and not browser", "-n", str(workers), "--dist", "loadgroup"],
        "browser": ["-m", "browser and not realtime", "-n", str(browser_workers), "--dist", "loadgroup"],
        "realtime": ["-m", "realtime", "-n", "0"],
    }


#: lint and type checks (make lint-checks), at the lowest CPU priority beside the first stage: the parallel
#: lane leaves the cores half idle after its first minute and a half, and the checks take about 1.5 min of
#: one core on a clean clone (mypy has no cache there). Under contention a niced process gets about 1.5 %
#: of a core, so the tests keep the CPU they had. Their output is printed whole when they end.
LINT = ["nice", "-n", "19", "make", "--no-print-directory", "lint-checks"]


def _relay(name: str, stream: IO[str]) -> None:
    """Print a lane's output line by line, each line tagged with the lane (two lanes share the terminal)."""
    for line in stream:
        print(f"[{name}] {line}", end="", flush=True)


class Lint:
    """The lint and type checks running in the background; ``finish`` prints their output, when they ended and
    their status."""

    def __init__(self) -> None:
        self.started = time.monotonic()
        self.ended = self.started
        self.output = ""
        self.proc = subprocess.Popen(LINT, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        print(f"\n=== lint: {' '.join(LINT)} (beside the first lane) ===", flush=True)

    def _read(self) -> None:
        assert self.proc.stdout is not None
        self.output = self.proc.stdout.read()
        self.proc.wait()
        self.ended = time.monotonic()

    def finish(self) -> int:
        self.reader.join()
        took = (self.ended - self.started) / 60
        print(f"\n=== lint: exit {self.proc.returncode} after {took:.1f} min ===\n{self.output}", end="", flush=True)
        return self.proc.returncode


def run_stage(
    names: tuple[str, ...], lane_args: dict[str, list[str]], pytest_args: list[str], workers: dict[str, int]
) -> dict[str, int]:
    """Start every lane of the stage at once and wait for all of them; returns each lane's exit status.
    Lanes side by side take consecutive port slices (tests/support/procs.py), one per worker."""
    port_slices = {name: sum(workers[n] for n in names[:i]) for i, name in enumerate(names)}
    procs: dict[str, tuple[subprocess.Popen[str], threading.Thread, float]] = {}
    for name in names:
        print(f"\n=== lane {name}: pytest {' '.join(lane_args[name])} ===", flush=True)
        cmd = [sys.executable, "-m", "pytest", "-q", *lane_args[name], f"--junitxml={RESULTS / f'junit-{name}.xml'}"]
        env = {**os.environ, "FLEET_TEST_PORT_SLICE": str(port_slices[name])}
        proc = subprocess.Popen(
            [*cmd, *pytest_args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
        )
        assert proc.stdout is not None
        relay = threading.Thread(target=_relay, args=(name, proc.stdout), daemon=True)
        relay.start()
        procs[name] = (proc, relay, time.monotonic())
    codes: dict[str, int] = {}
    for name, (proc, relay, t0) in procs.items():
        codes[name] = proc.wait()
        relay.join()
        print(f"=== lane {name}: exit {codes[name]} after {(time.monotonic() - t0) / 60:.1f} min ===", flush=True)
    return codes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=int(os.environ.get("FLEET_TEST_WORKERS", "4")))
    ap.add_argument("--browser-workers", type=int, default=int(os.environ.get("FLEET_TEST_BROWSER_WORKERS", "2")))
    ap.add_argument("--lint", action="store_true", help="run make lint-checks at low priority beside the first lane")
    args, pytest_args = ap.parse_known_args(argv)
    RESULTS.mkdir(exist_ok=True)
    for old in RESULTS.glob("junit-*.xml"):
        old.unlink()
    codes: dict[str, int] = {}
    started = time.monotonic()
    lane_args = lanes(args.workers, args.browser_workers)
    workers = {"parallel": args.workers, "browser": args.browser_workers, "realtime": 1}
    lint = Lint() if args.lint else None
    for i, stage in enumerate(STAGES):
        codes.update(run_stage(stage, lane_args, pytest_args, workers))
        if i == 0 and lint is not None:  # lint ends before the next stage: the realtime lane wants a quiet machine
            codes["lint"] = lint.finish()
    ran = [c for c in codes.values() if c != NO_TESTS]
    status = max(ran) if ran else NO_TESTS
    print(f"\n=== all lanes: {(time.monotonic() - started) / 60:.1f} min; exit {status} ===", flush=True)
    subprocess.call([sys.executable, str(ROOT / "scripts" / "test_report.py"), "--slowest", "10"], cwd=ROOT)
    print(closing_line(lint_failed=codes.get("lint", 0) != 0))
    return status


def closing_line(lint_failed: bool = False) -> str:
    """The failed tests by name, each with its message on the line below, then the counts as one plain
    ``N passed, N failed, N skipped`` line, the last the run prints."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from test_report import read_lane

    cases = [c for p in sorted(RESULTS.glob("junit-*.xml")) for c in read_lane(p).cases]
    outcomes = [c.outcome for c in cases]
    failed = [f"{c.outcome}: [{c.lane}] {c.nodeid}\n    {c.reason}" for c in cases if c.outcome in ("failed", "error")]
    # The failures' names come just above the total: CI keeps only the tail of a run's output.
    counts = f"total: {outcomes.count('passed')} passed, {len(failed)} failed, {outcomes.count('skipped')} skipped"
    if lint_failed:
        failed.insert(0, "failed: lint and type checks (make lint-checks: its output is above, after === lint)")
    return "\n".join([*failed, counts])


if __name__ == "__main__":
    sys.exit(main())
