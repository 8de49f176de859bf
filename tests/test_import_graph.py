"""The package's import graph has no cycle and no import from a lower layer to a higher one.

The layers are the table under "## Layers" in ``docs/architecture.md``, read from there so they are
written once. Every module of ``dls_quadruped/`` is parsed with ``ast`` (nothing is imported); an edge
is an ``import`` or ``from ... import`` of a package module, at module level or inside a function
(a lazy import still runs the module), except under ``if TYPE_CHECKING:`` (annotations only).
``from pkg import name`` is an edge to ``pkg.name`` where that is a module, else to ``pkg``; the
implicit import of a module's parent packages is not an edge.
"""

from __future__ import annotations

import ast
import fnmatch
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "dls_quadruped"
ARCHITECTURE = REPO / "docs" / "architecture.md"

KNOWN_UPWARD: dict[tuple[str, str], str] = {}
"""Upward imports (importer, imported: paths under ``dls_quadruped/``) not removed yet, each with its fix.
An entry whose import is gone fails :func:`test_known_upward_edges_still_exist`: delete it then."""


@dataclass(frozen=True)
class Edge:
    """``importer`` imports ``imported`` (module names) at ``line`` of the importer's file."""

    importer: str
    imported: str
    line: int


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@cache
def modules() -> dict[str, Path]:
    """Module name -> file, for every ``.py`` file of the package (a package is its ``__init__.py``)."""
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def rel(module: str) -> str:
    """The module's file relative to ``dls_quadruped/`` (``sim/interface.py``)."""
    return modules()[module].relative_to(PACKAGE).as_posix()


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of ``tree`` outside the bodies of ``if TYPE_CHECKING:``."""
    found = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for other in child.orelse:
                    visit(other)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found.append(child)
            visit(child)

    visit(tree)
    return found


def _targets(module: str, node: ast.Import | ast.ImportFrom) -> list[str]:
    """The package modules one import statement of ``module`` names ("?name" where none exists)."""
    mods = modules()
    if isinstance(node, ast.Import):
        return [a.name if a.name in mods else f"?{a.name}" for a in node.names
                if a.name.split(".")[0] == "dls_quadruped"]
    if node.level:  # relative: from the module's package, one level up per extra dot
        base = module.split(".") if mods[module].name == "__init__.py" else module.split(".")[:-1]
        base = base[:len(base) - (node.level - 1)]
        source = ".".join([*base, node.module] if node.module else base)
    else:
        source = node.module or ""
    if source.split(".")[0] != "dls_quadruped":
        return []
    out = []
    for alias in node.names:
        if f"{source}.{alias.name}" in mods:
            out.append(f"{source}.{alias.name}")
        else:
            out.append(source if source in mods else f"?{source}")
    return out


@cache
def edges() -> tuple[Edge, ...]:
    """Every import of a package module by another, in file order."""
    out = []
    for module, path in modules().items():
        for node in _imports(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            out.extend(Edge(module, target, node.lineno) for target in _targets(module, node) if target != module)
    return tuple(out)


@cache
def layers() -> list[tuple[str, list[str]]]:
    """(layer name, path patterns) of the "## Layers" table of docs/architecture.md, lowest first."""
    text = ARCHITECTURE.read_text(encoding="utf-8")
    section = text.split("\n## Layers\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("|") and not line.startswith("|---")][1:]
    out = []
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        out.append((cells[0], re.findall(r"`([^`]+)`", cells[1])))
    return out


def layer_of(path: str) -> int:
    """Index in :func:`layers` of the file ``path`` (relative to ``dls_quadruped/``): a file pattern
    (``mpc/run.py``, ``*/__main__.py``) before a folder (``mpc/``), a deeper folder before a shallower one."""
    best: tuple[int, int] | None = None  # (specificity, layer)
    for index, (_, patterns) in enumerate(layers()):
        for pattern in patterns:
            if pattern.endswith("/"):
                score = len(pattern) if path.startswith(pattern) else -1
            else:
                score = 10_000 if fnmatch.fnmatch(path, pattern) else -1
            if score >= 0 and (best is None or score > best[0]):
                best = (score, index)
    if best is None:
        raise AssertionError(f"dls_quadruped/{path} is in no layer of docs/architecture.md '## Layers'")
    return best[1]


def cycles(graph_edges: tuple[Edge, ...]) -> list[list[Edge]]:
    """One cycle (its edges in order) through each strongly connected component of more than one module."""
    graph: dict[str, dict[str, Edge]] = {m: {} for m in modules()}
    for e in graph_edges:
        if e.imported in graph:
            graph[e.importer].setdefault(e.imported, e)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    components: list[set[str]] = []

    def connect(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while not component or w != v:
                w = stack.pop()
                component.add(w)
            if len(component) > 1:
                components.append(component)

    for v in sorted(graph):
        if v not in index:
            connect(v)
    found = []
    for component in components:  # the shortest way from its first module back to itself, breadth first
        start = min(component)
        parent: dict[str, Edge] = {}
        frontier = [start]
        while start not in parent:
            nxt = []
            for v in frontier:
                for w, e in graph[v].items():
                    if w in component and w not in parent:
                        parent[w] = e
                        nxt.append(w)
            frontier = nxt
        path = [parent[start]]
        while path[-1].importer != start:
            path.append(parent[path[-1].importer])
        found.append(path[::-1])
    return found


def upward(graph_edges: tuple[Edge, ...]) -> list[Edge]:
    """The edges from a module to a module of a higher layer."""
    return [e for e in graph_edges if not e.imported.startswith("?")
            and layer_of(rel(e.imported)) > layer_of(rel(e.importer))]


def _show(e: Edge) -> str:
    return f"dls_quadruped/{rel(e.importer)}:{e.line} imports {e.imported}"


def test_the_graph_sees_the_package():
    """The walk finds the modules and their imports, lazy ones included, ``TYPE_CHECKING`` ones left out."""
    found = {(e.importer, e.imported): e.line for e in edges()}
    assert len(modules()) > 100 and len(found) > 300
    assert ("dls_quadruped.envs.env", "dls_quadruped.envs.managers.reward") in found  # at module level
    assert ("dls_quadruped.sim.registry", "dls_quadruped.sim.warp_backend") in found  # inside a function
    shard = modules()["dls_quadruped.sim.shard"].read_text().splitlines()
    dynamics = [e.line for e in edges() if (e.importer, e.imported) == ("dls_quadruped.sim.shard",
                                                                         "dls_quadruped.control.dynamics")]
    assert [n for n, line in enumerate(shard, 1) if "import LegDynamics" in line] == [44, 99]
    assert shard[42] == "if TYPE_CHECKING:" and dynamics == [99]  # the lazy import, not the one for annotations


def test_every_import_names_a_module():
    missing = [f"{_show(e)}: no such module" for e in edges() if e.imported.startswith("?")]
    assert not missing, "\n".join(missing)


def test_every_module_has_one_layer_and_every_pattern_a_module():
    names = [name for name, _ in layers()]
    assert len(names) >= 10 and len(set(names)) == len(names), names
    for module in modules():
        layer_of(rel(module))
    paths = [rel(m) for m in modules()]
    unused = [p for _, patterns in layers() for p in patterns
              if not any(q.startswith(p) if p.endswith("/") else fnmatch.fnmatch(q, p) for q in paths)]
    assert not unused, f"docs/architecture.md '## Layers' names what the package does not have: {unused}"


def test_no_import_cycle():
    found = cycles(edges())
    assert not found, "import cycles (one way round each):\n" + "\n".join(
        "  " + " -> ".join([*(f"dls_quadruped/{rel(e.importer)}:{e.line}" for e in c),
                            f"dls_quadruped/{rel(c[0].importer)}"])
        for c in found)


def test_no_import_from_a_lower_layer_to_a_higher_one():
    names = [name for name, _ in layers()]
    bad = [f"{_show(e)}: {names[layer_of(rel(e.importer))]} -> {names[layer_of(rel(e.imported))]}"
           for e in upward(edges()) if (rel(e.importer), rel(e.imported)) not in KNOWN_UPWARD]
    assert not bad, "imports from a lower layer to a higher one (docs/architecture.md '## Layers'):\n" + "\n".join(bad)


@pytest.mark.parametrize("known", sorted(KNOWN_UPWARD))
def test_known_upward_edges_still_exist(known):
    assert known in {(rel(e.importer), rel(e.imported)) for e in upward(edges())}, \
        f"{known} is no longer an upward import: remove it from KNOWN_UPWARD"


def test_the_checks_find_what_they_look_for():
    """A cycle and an upward import planted in the graph are both reported, and layers come from the table."""
    planted = (Edge("dls_quadruped.core.state", "dls_quadruped.envs.env", 7),)
    cycle = [c for c in cycles(edges() + planted) if planted[0] in c]
    assert len(cycle) == 1 and cycle[0][0].importer == cycle[0][-1].imported
    assert all(a.imported == b.importer for a, b in zip(cycle[0], cycle[0][1:], strict=False))
    assert planted[0] in upward(edges() + planted)
    name = {path: layers()[layer_of(path)][0] for path in ("core/state.py", "eval/rollout.py", "eval/__main__.py")}
    assert name["core/state.py"] == "core" and name["eval/rollout.py"] == "eval" != name["eval/__main__.py"]
