"""Every source file of the package is at most 400 lines (a module that grows past it is split along a seam)."""

from __future__ import annotations

from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "dls_quadruped"
LIMIT = 400


def test_every_package_source_file_is_at_most_400_lines():
    sizes = {p.relative_to(PACKAGE).as_posix(): len(p.read_text().splitlines())
             for ext in ("*.py", "*.cpp", "*.h") for p in PACKAGE.rglob(ext)}
    assert len(sizes) > 100, "the walk found too few files to be the package"
    over = {name: n for name, n in sorted(sizes.items()) if n > LIMIT}
    assert not over, f"files over {LIMIT} lines: {over}"
