"""Every test the docs name still exists: docs/safety.md and the others say which test proves each promise
(``tests/x/test_y.py::test_z``, or a bare `test_z` under a "Tests:" line), so merging or moving a test
cannot silently orphan a promise."""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted(
    ["README.md", "deploy/README.md", *(str(p.relative_to(ROOT)) for p in sorted((ROOT / "docs").glob("*.md")))]
)
#: ``tests/a/test_b.py``, optionally ``::Class::test_c[param]``
FULL_REF = re.compile(r"(tests/[\w/]+\.py)((?:::[\w]+)*)(\[[^\]\s`]*\])?")
#: a bare test name in backticks: `test_c`, `test_c[param]`, or an abbreviation `test_c_...`
BARE_REF = re.compile(r"`(test_\w+?)(\.\.\.)?(\[[^\]`]*\])?`")


@cache
def defined_tests(path: Path) -> frozenset[str]:
    """Test functions of a module: ``test_x`` and ``TestY::test_x``."""
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name.startswith("test"):
            names.add(node.name)
        elif isinstance(node, ast.ClassDef) and node.name.startswith("Test"):
            names |= {
                f"{node.name}::{f.name}"
                for f in node.body
                if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef) and f.name.startswith("test")
            }
    return frozenset(names)


@cache
def every_test_name() -> frozenset[str]:
    return frozenset(name.rsplit("::", 1)[-1] for p in (ROOT / "tests").rglob("test_*.py") for name in defined_tests(p))


def missing_references(text: str, root: Path = ROOT) -> list[str]:
    """The test references in ``text`` that name no existing file, test or parameter."""
    missing: list[str] = []
    for m in FULL_REF.finditer(text):
        file, names, param = m.group(1), m.group(2).lstrip(":"), m.group(3)
        path = root / file
        if (
            not path.exists()
            or (names and names not in defined_tests(path))
            or (param and param.strip("[]") not in path.read_text())
        ):
            missing.append(m.group(0))
    known = every_test_name() if root == ROOT else frozenset()
    for m in BARE_REF.finditer(text):
        name, abbreviated = m.group(1), m.group(2)
        found = any(t.startswith(name) for t in known) if abbreviated else name in known
        if not found:
            missing.append(m.group(0))
    return missing


@pytest.mark.parametrize("doc", DOCS)
def test_every_test_a_doc_names_exists(doc: str) -> None:
    assert missing_references((ROOT / doc).read_text()) == [], f"{doc} names tests that do not exist"


def test_the_check_finds_a_missing_test_a_missing_file_and_a_missing_parameter() -> None:
    """The check can fail: each kind of stale reference is reported, and the real ones are not."""
    real = "tests/deploy/test_docs_test_references.py::test_every_test_a_doc_names_exists"
    text = (
        f"`{real}` and `tests/deploy/test_docs_test_references.py` and `test_every_test_a_doc_names_exists` and "
        "`test_the_check_finds_...` | "
        "`tests/deploy/test_docs_test_references.py::test_merged_away` "
        "`tests/deploy/test_moved_away.py` "
        "`tests/deploy/test_docs.py::test_links_resolve[docs/no-such-doc.md]` "
        "`test_renamed_long_ago` `test_nothing_starts_like_this_...`"
    )
    assert missing_references(text) == [
        "tests/deploy/test_docs_test_references.py::test_merged_away",
        "tests/deploy/test_moved_away.py",
        "tests/deploy/test_docs.py::test_links_resolve[docs/no-such-doc.md]",
        "`test_renamed_long_ago`",
        "`test_nothing_starts_like_this_...`",
    ]
