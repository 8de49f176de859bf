"""Code speaks of the code (STYLE.md principle 13): no issue, item or SPEC numbers in the package or in
``docs/architecture.md``.

Those numbers point at a tracker and a spec file the repository does not carry, and their history
("before issue 12", "issue 25's fix") belongs in git and in the ``docs/`` pages that report results.
Package text cites the thesis (sections, equations, tables) or says what the code does instead.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "dls_quadruped"
SUFFIXES = {".py", ".cpp", ".h", ".xml", ".yaml", ".yml", ".md"}
"""Text files of the package that are searched (sources, the C++ kernels, the MJCF)."""

REFERENCE = re.compile(r"\b[Ii]ssues? #?[0-9]+|\bSPEC\b|\b[Ii]tems? [0-9]+[a-z]?\b")
"""An issue ("issue 26", "Issue 8", "issues 12"), an item ("item 9a") or the spec ("SPEC 9", "SPEC section 4")."""

PENDING: set[str] = set()
"""Files excused from the check (none)."""


def checked_files() -> list[Path]:
    """The package's text files and docs/architecture.md, less :data:`PENDING`."""
    files = [p for p in sorted(PACKAGE.rglob("*")) if p.is_file() and p.suffix in SUFFIXES]
    files.append(REPO / "docs" / "architecture.md")
    return [p for p in files if p.relative_to(REPO).as_posix() not in PENDING]


def offenders(path: Path) -> list[str]:
    """``file:line: text`` of every line of ``path`` that names an issue, item or SPEC number."""
    rel = path.relative_to(REPO).as_posix()
    lines = path.read_text(encoding="utf-8").splitlines()
    return [f"{rel}:{i}: {line.strip()[:120]}" for i, line in enumerate(lines, 1) if REFERENCE.search(line)]


@pytest.mark.parametrize("text", [
    "(issue 14)", "issue 26 item 2", "issue 25's fix", "Issue 8: self-collision", "issues 12 and 14",
    "issue #7", "item 9a", "SPEC 9", "SPEC section 4", "(SPEC 8-9)",
])
def test_the_pattern_finds_references(text):
    assert REFERENCE.search(text)


@pytest.mark.parametrize("text", [
    "STATE_SPECS", "COMMAND_SPECS.items()", "tissue 3", "items", "thesis 3.2, Algorithm 2", "Table 13",
])
def test_the_pattern_leaves_code_and_thesis_citations_alone(text):
    assert not REFERENCE.search(text)


def test_package_and_architecture_name_no_issue_item_or_spec():
    files = checked_files()
    assert any(p.name == "architecture.md" for p in files) and len(files) > 100  # the walk found the package
    found = [line for path in files for line in offenders(path)]
    assert not found, ("issue/item/SPEC references (cite the thesis or say what the code does; history "
                       "belongs in git):\n" + "\n".join(found))
