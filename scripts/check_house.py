"""The house's shape, checked in ``make lint`` (and drawn into docs/architecture.md, so the page cannot drift).

- No Python file outside the tests is over ``MAX_LINES`` lines (migrations aside), and no module of the
  dashboard (``frontend/js``): split along a seam.
- ``backend/services/`` holds domain folders and at most ``MAX_LOOSE`` modules at its top (``__init__``
  included), and every domain folder is a layer of the "server domains" import-linter contract.
- README.md's repository table names every top-level folder and every domain folder.
- docs/architecture.md holds the domains' diagram and rules as this script draws them from that contract,
  the domains' own docstrings and the imports the code has today.

``python scripts/check_house.py`` checks; ``--write`` redraws the block in docs/architecture.md.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SERVICES = ROOT / "backend" / "services"
DOC = ROOT / "docs" / "architecture.md"
MAX_LINES = 400
MAX_LOOSE = 4
CONTRACT = "server domains: each imports only the domains below it"
BEGIN = "<!-- domains: drawn by scripts/check_house.py --write; make lint checks it -->"
END = "<!-- end of domains -->"


def oversized() -> list[str]:
    """Python files of the project (tests and migrations aside) and dashboard modules over MAX_LINES lines."""
    files = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "*.py", "frontend/js/*.js"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    out = []
    for name in files:
        if name.startswith("tests/") or "/migrations/" in name or not (ROOT / name).is_file():
            continue
        n = len((ROOT / name).read_text(encoding="utf-8").splitlines())
        if n > MAX_LINES:
            out.append(f"{name}: {n} lines (at most {MAX_LINES}: split it along a seam)")
    return out


def layers() -> list[list[str]]:
    """The contract's layers, top first, each a list of sibling domains (the composition root included)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    for contract in config["tool"]["importlinter"]["contracts"]:
        if contract["name"] == CONTRACT:
            return [[name.strip() for name in layer.split("|")] for layer in contract["layers"]]
    raise SystemExit(f"pyproject.toml has no import-linter contract named {CONTRACT!r}")


def domains() -> list[str]:
    return sorted(p.name for p in SERVICES.iterdir() if (p / "__init__.py").is_file())


def holds(domain: str) -> str:
    """What a domain holds: the first paragraph of its package docstring, on one line."""
    doc = ast.get_docstring(ast.parse((SERVICES / domain / "__init__.py").read_text(encoding="utf-8"))) or ""
    return " ".join(doc.split("\n\n")[0].split())


def imports_between(names: list[str]) -> set[tuple[str, str]]:
    """(a, b): some module of domain a imports one of domain b today (import-linter's graph library)."""
    import grimp

    graph = grimp.build_graph("backend")
    found = set()
    for a in names:
        for module in graph.find_descendants(f"backend.services.{a}") | {f"backend.services.{a}"}:
            for imported in graph.find_modules_directly_imported_by(module):
                parts = imported.split(".")
                if len(parts) > 2 and parts[:2] == ["backend", "services"] and parts[2] in names and parts[2] != a:
                    found.add((a, parts[2]))
    return found


def drawn() -> str:
    """The block of docs/architecture.md: the diagram and the table of rules."""
    stack = layers()
    names = domains()
    edges = imports_between(names)
    lines = [BEGIN, "", "```mermaid", "flowchart TD"]
    for level, siblings in enumerate(stack):
        present = [d for d in siblings if d in names]
        if present:
            lines.append(f'    subgraph L{level} [" "]')
            lines.extend(f"        {d}" for d in present)
            lines.append("    end")
    lines.extend(f"    {a} --> {b}" for a, b in sorted(edges))
    lines += ["```", "", "| domain | holds | may import (the domains on the rows below it) |", "|---|---|---|"]
    for level, siblings in enumerate(stack):
        below = [d for layer in stack[level + 1 :] for d in layer if d in names]
        for d in siblings:
            if d in names:
                rule = ", ".join(f"`{b}`" for b in below) or "no other domain"
                lines.append(f"| `{d}/` | {holds(d)} | {rule} |")
    lines += ["", END]
    return "\n".join(lines)


def unnamed_in_readme() -> list[str]:
    """Top-level folders and domain folders that the README's repository table does not name."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    table = text[text.index("## Repository") :].split("\n\n")[1] if "## Repository" in text else ""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    tops = sorted({f.split("/")[0] for f in files if "/" in f and not f.startswith(".")})
    out = [f"README.md's repository table does not name {top}/" for top in tops if f"`{top}/`" not in table]
    out += [f"README.md's repository table does not name services' {d}/" for d in domains() if f"`{d}/`" not in table]
    return out


def problems() -> list[str]:
    out = oversized() + unnamed_in_readme()
    stack = [d for layer in layers() for d in layer]
    for d in domains():
        if d not in stack:
            out.append(f"backend/services/{d}/ is in no layer of the import-linter contract {CONTRACT!r}")
        if not holds(d):
            out.append(f"backend/services/{d}/__init__.py has no docstring saying what the domain holds")
    loose = sorted(p.name for p in SERVICES.glob("*.py"))
    if len(loose) > MAX_LOOSE:
        out.append(f"backend/services/ has {len(loose)} loose modules (at most {MAX_LOOSE}): {', '.join(loose)}")
    text = DOC.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        out.append("docs/architecture.md has no domains block: run python scripts/check_house.py --write")
    elif text[text.index(BEGIN) : text.index(END) + len(END)] != drawn():
        out.append("docs/architecture.md's domains block is out of date: run python scripts/check_house.py --write")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="redraw the domains block of docs/architecture.md")
    args = ap.parse_args()
    if args.write:
        text = DOC.read_text(encoding="utf-8")
        if BEGIN in text and END in text:
            text = text[: text.index(BEGIN)] + drawn() + text[text.index(END) + len(END) :]
        else:
            raise SystemExit(f"docs/architecture.md needs the markers {BEGIN!r} and {END!r} where the block goes")
        DOC.write_text(text, encoding="utf-8")
    found = problems()
    for line in found:
        print(f"house: {line}", file=sys.stderr)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
