"""Every tutorial of ``docs/tutorials/`` runs as written: its code blocks, in page order, at the tiny sizes the
page uses.

How a page is run (one fresh namespace per page, in a temporary folder that holds ``docs/``, ``tasks/`` and
``experiments/`` as links to the repository's, so the page's relative paths work as they do in a clone):

* a ``python`` block is executed; a ``python`` block right after the line
  ``<!-- tutorial: in MODULE -->`` is executed inside that module (as if its code were added to the module's
  file: a function defined there is the module's own, which is how the managers find term functions);
* a ``yaml`` block whose first line is ``# file: PATH`` is written to ``PATH`` first;
* other blocks (``bash``: commands the page shows; their make targets and flags are checked by
  ``tests/test_docs_commands.py``) are not run.

What a page adds to a module, a module-level table or a registry (a term function, a mirror map, a controller,
an MPC kernel) is removed after it,
so the pages run in any order and leave the package as it was. The pages assert what they show (``assert``
lines are part of the tutorial: the reader sees what to expect).
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TUTORIALS = REPO / "docs" / "tutorials"
PAGES = sorted(p for p in TUTORIALS.glob("*.md") if p.name != "index.md")
IN_MODULE = re.compile(r"^<!-- tutorial: in ([\w.]+) -->$")
FENCE = re.compile(r"^```([\w-]*)\s*$")


def blocks(text: str) -> list[tuple[str, str, str | None]]:
    """(language, code, module it runs in or None) of every fenced block of a page, in order."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        prev = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        module = IN_MODULE.match(prev.strip())
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        out.append((m.group(1), "\n".join(lines[i + 1:j]) + "\n", module.group(1) if module else None))
        i = j + 1
    return out


def test_the_reader_finds_blocks_files_and_modules():
    page = ("text\n```yaml\n# file: a/b.yaml\nx: 1\n```\n<!-- tutorial: in json -->\n\n```python\ny = 2\n```\n"
            "```bash\nmake x\n```\n")
    assert blocks(page) == [("yaml", "# file: a/b.yaml\nx: 1\n", None), ("python", "y = 2\n", "json"),
                            ("bash", "make x\n", None)]


def test_there_are_tutorials():
    names = {p.stem for p in PAGES}
    assert {"task_file", "reward_term", "observation", "controller", "mpc_cost", "experiment"} <= names, names
    index = (TUTORIALS / "index.md").read_text()
    assert all(f"({p.name})" in index for p in PAGES), "docs/tutorials/index.md lists every tutorial"


def _registries() -> list:
    """The registries a page may add to, with their built-in entries registered (``controllers`` registers the
    built-in controllers when it is imported), so the snapshot taken before a page holds them."""
    from dls_quadruped.closed_loop import controllers  # noqa: F401 -- registers the built-in controllers
    from dls_quadruped.closed_loop.registry import CONTROLLER_REGISTRY
    from dls_quadruped.mpc.kernel_registry import KERNEL_REGISTRY

    return [CONTROLLER_REGISTRY, KERNEL_REGISTRY]


@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_tutorial_runs(page, tmp_path, monkeypatch):
    """The page's blocks run in order; afterwards the built-in controllers and kernels are all still there and
    nothing the page registered is."""
    for name in ("docs", "tasks", "experiments"):
        (tmp_path / name).symlink_to(REPO / name)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    registries = {id(r): (r, set(r.names())) for r in _registries()}
    touched: dict[str, set[str]] = {}
    tables: dict[str, dict[str, dict]] = {}
    namespace: dict = {"__name__": f"tutorial_{page.stem}"}
    code_blocks = blocks(page.read_text())
    assert any(lang == "python" for lang, _, _ in code_blocks), f"{page.name}: no python block"
    try:
        for lang, code, module_name in code_blocks:
            if lang == "yaml" and code.startswith("# file: "):
                path = Path(code.splitlines()[0].removeprefix("# file: ").strip())
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(code)
            elif lang == "python" and module_name is not None:
                module = importlib.import_module(module_name)
                if module_name not in touched:
                    touched[module_name] = set(vars(module))
                    tables[module_name] = {k: dict(v) for k, v in vars(module).items() if type(v) is dict}
                exec(compile(code, f"{page.name} (in {module_name})", "exec"), vars(module))  # noqa: S102
            elif lang == "python":
                exec(compile(code, page.name, "exec"), namespace)  # noqa: S102
    finally:
        for module_name, before in touched.items():
            module = importlib.import_module(module_name)
            for added in set(vars(module)) - before:
                delattr(module, added)
            for name, saved in tables[module_name].items():  # a module-level table the page added to
                table = getattr(module, name)
                table.clear()
                table.update(saved)
        for registry, before in registries.values():
            for added in set(registry.names()) - before:
                registry.unregister(added)
            assert set(registry.names()) == before
