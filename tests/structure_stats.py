"""The package's structure in numbers, for docs/architecture.md "Structure, measured".

Run from a checkout: ``python tests/structure_stats.py`` (prints a markdown table row source, one figure a line).
It reads the files of ``dls_quadruped/`` beside it and uses ``tests/test_import_graph.py``'s parser, so the import
edges, upward imports and cycles are the ones that test checks. Not a test (pytest collects ``test_*.py`` only).

Counted:
    modules, lines: ``.py`` files of the package and their lines.
    import edges, upward imports, cycles: as ``tests/test_import_graph.py`` finds them (an upward import listed in its
        ``KNOWN_UPWARD`` still counts).
    files >= 391 lines: within 10 lines of the 400-line cap (docs/STYLE.md principle 16).
    lines > 120 characters: longer than ruff's ``E501`` limit.
    hand-written compiled/eager twins: a ``def <name>_eager`` function, or a ``Fused(...)`` built by hand outside
        ``core/compile.py`` (one function made twice: an eager one and a compiled wrapper kept beside it).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import test_import_graph as graph

CAP = 400
NEAR = 10
LONG = 120


def twins_in(path: str, text: str) -> list[str]:
    """The hand-written compiled/eager twins of one file (``path`` relative to ``dls_quadruped/``): each
    ``def <name>_eager(`` and, outside ``core/compile.py``, each ``Fused(`` call, as the matched text."""
    found = [m.strip() for m in re.findall(r"^[ \t]*def \w+_eager\(", text, flags=re.MULTILINE)]
    if path != "core/compile.py":
        found += re.findall(r"(?<![\w.])Fused\(", text)
    return found


def measure() -> dict[str, int]:
    """The figures of the module doc, for the checkout this file is in."""
    files = sorted(graph.PACKAGE.rglob("*.py"))
    texts = {p: p.read_text(encoding="utf-8") for p in files}
    lines = {p: t.splitlines() for p, t in texts.items()}
    edges = graph.edges()
    twins = sum(len(twins_in(p.relative_to(graph.PACKAGE).as_posix(), t)) for p, t in texts.items())
    return {
        "modules": len(files),
        "lines": sum(len(v) for v in lines.values()),
        "import edges": len({(e.importer, e.imported) for e in edges}),
        "upward imports": len(graph.upward(edges)),
        "import cycles": len(graph.cycles(edges)),
        f"files >= {CAP - NEAR + 1} lines": sum(len(v) > CAP - NEAR for v in lines.values()),
        f"files > {CAP} lines": sum(len(v) > CAP for v in lines.values()),
        f"lines > {LONG} characters": sum(len(line) > LONG for v in lines.values() for line in v),
        "hand-written compiled/eager twins": twins,
    }


if __name__ == "__main__":
    argparse.ArgumentParser(description="The package's structure in numbers (module doc); takes no arguments.",
                            prog="python tests/structure_stats.py").parse_args()
    for name, value in measure().items():
        print(f"{name}: {value}")
