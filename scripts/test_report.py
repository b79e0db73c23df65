"""``make test-report``: the slowest tests and the time per folder, read from the JUnit reports that every
``make test`` writes (``test-results/junit-*.xml``, one per lane; docs/testing.md).

Each test's time is split into setup, call and teardown (properties the suite's conftest records); a folder's
time is the sum of its tests' times, which in the parallel lane is more than the wall clock it took.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "test-results"


@dataclass
class Case:
    nodeid: str
    lane: str
    seconds: float
    phases: dict[str, float] = field(default_factory=dict)
    outcome: str = "passed"
    reason: str = ""

    @property
    def folder(self) -> str:
        return self.nodeid.split("::", 1)[0].rsplit("/", 1)[0]


@dataclass
class Lane:
    name: str
    wall_s: float
    cases: list[Case]


def _nodeid(case: ET.Element) -> str:
    """``tests/x/test_y.py::test_z[param]`` from a testcase element (xunit1 has ``file``; else the classname)."""
    name = case.get("name", "")
    classname = case.get("classname", "")
    file = case.get("file")
    if file:
        module = file
        parts = classname.split(".")
        stem = Path(file).stem
        inner = parts[parts.index(stem) + 1 :] if stem in parts else []
    elif not classname:  # an error outside any test (collection): the name is the file or the node
        return name.replace(".", "/").removesuffix("/py") + (".py" if not name.endswith(".py") else "")
    else:
        parts = classname.split(".")
        split = next((i for i in range(len(parts), 0, -1) if parts[i - 1].startswith("test")), len(parts))
        module = "/".join(parts[:split]) + ".py"
        inner = parts[split:]
    return "::".join([module, *inner, name])


def _outcome(case: ET.Element) -> str:
    for tag in ("failure", "error", "skipped"):
        if case.find(tag) is not None:
            return {"failure": "failed", "error": "error", "skipped": "skipped"}[tag]
    return "passed"


def _reason(case: ET.Element, limit: int = 400) -> str:
    """A failed test's message on one line (pytest's first line of the assertion, or the error), cut to
    ``limit`` characters: CI keeps only the tail of a run, where the failures' names and these are printed."""
    for tag in ("failure", "error"):
        found = case.find(tag)
        if found is not None:
            text = " ".join((found.get("message") or found.text or "").split())
            return text if len(text) <= limit else text[: limit - 3] + "..."
    return ""


def read_lane(path: Path) -> Lane:
    root = ET.parse(path).getroot()
    suites = [root] if root.tag == "testsuite" else list(root.iter("testsuite"))
    lane = path.stem.removeprefix("junit-")
    cases: list[Case] = []
    wall = 0.0
    for suite in suites:
        wall += float(suite.get("time", 0))
        for case in suite.iter("testcase"):
            phases = {
                p.get("name", "").removesuffix("_s"): float(p.get("value", 0))
                for p in case.iter("property")
                if p.get("name", "").endswith("_s")
            }
            cases.append(Case(_nodeid(case), lane, float(case.get("time", 0)), phases, _outcome(case), _reason(case)))
    return Lane(lane, wall, cases)


def report(lanes: list[Lane], slowest: int) -> str:
    out: list[str] = []
    cases = [c for lane in lanes for c in lane.cases]
    counts: dict[str, int] = defaultdict(int)
    for c in cases:
        counts[c.outcome] += 1
    out.append("lanes: " + ", ".join(f"{ln.name} {len(ln.cases)} tests in {ln.wall_s / 60:.1f} min" for ln in lanes))
    out.append(
        f"total: {len(cases)} tests ({', '.join(f'{n} {k}' for k, n in sorted(counts.items()))}), "
        f"wall clock {sum(ln.wall_s for ln in lanes) / 60:.1f} min"
    )
    out.append("")
    out.append(f"{slowest} slowest tests (seconds: total = setup + call + teardown; lane)")
    for c in sorted(cases, key=lambda c: c.seconds, reverse=True)[:slowest]:
        split = " + ".join(f"{c.phases.get(p, 0.0):.1f}" for p in ("setup", "call", "teardown"))
        out.append(f"{c.seconds:7.1f}  = {split:<20} {c.lane:<9} {c.nodeid}")
    heavy = sorted((c for c in cases if "cpu" in c.phases), key=lambda c: c.phases["cpu"], reverse=True)
    if heavy:
        out.append("")
        cpu_min = ", ".join(f"{ln.name} {sum(c.phases.get('cpu', 0.0) for c in ln.cases) / 60:.1f}" for ln in lanes)
        out.append(f"{slowest} heaviest tests (CPU seconds of the test and every process it started; lane)")
        out.append(f"CPU minutes per lane: {cpu_min}")
        for c in heavy[:slowest]:
            out.append(f"{c.phases['cpu']:7.1f}  of {c.seconds:6.1f} s  {c.lane:<9} {c.nodeid}")
    out.append("")
    out.append("time per folder (sum of its tests' times; tests)")
    folders: dict[str, list[Case]] = defaultdict(list)
    for c in cases:
        folders[c.folder].append(c)
    for folder, group in sorted(folders.items(), key=lambda kv: -sum(c.seconds for c in kv[1])):
        out.append(f"{sum(c.seconds for c in group) / 60:6.1f} min  {len(group):4d}  {folder}")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reports", nargs="*", type=Path, help="JUnit XML files (default: test-results/junit-*.xml)")
    ap.add_argument("--slowest", type=int, default=30, help="how many of the slowest tests to list")
    args = ap.parse_args(argv)
    paths = args.reports or sorted(RESULTS.glob("junit-*.xml"))
    if not paths:
        print(f"no JUnit report in {RESULTS}: run `make test` first", file=sys.stderr)
        return 1
    print(report([read_lane(p) for p in paths], args.slowest))
    return 0


if __name__ == "__main__":
    sys.exit(main())
