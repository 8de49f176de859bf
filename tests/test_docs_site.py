"""The documentation site builds with ``mkdocs build --strict`` (``make docs``): every warning is an error, a link
or anchor that leads nowhere inside the site included, and the API pages are generated from the docstrings.
Plus the site's hook (``dls_quadruped/tools/docs_hooks.py``), which turns links that leave ``docs/`` into
repository paths, on hand-made pages."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dls_quadruped.tools.docs_hooks import rewrite_outside_links

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"


def test_links_that_leave_the_docs_become_repository_paths():
    md = ("see [the README](../README.md), [a task](../tasks/base.yaml#L1), [`tasks/rough.yaml`](../tasks/rough.yaml), "
          "[train](train.md), [gone](../no_such_file.md), [web](https://x.org/a), ![img](learning_curve_base.png)\n"
          "```\n[code](../README.md)\n```")
    out = rewrite_outside_links(md, "workflow.md", DOCS)
    assert "see the README (`README.md`), a task (`tasks/base.yaml`), `tasks/rough.yaml`, [train](train.md)" in out
    assert "[gone](../no_such_file.md)" in out and "[web](https://x.org/a)" in out and "![img](" in out
    assert out.endswith("```\n[code](../README.md)\n```")  # code blocks are left alone
    nested = rewrite_outside_links("[eval](../eval.md), [top](../../README.md)", "experiments/x.md", DOCS)
    assert nested == "[eval](../eval.md), top (`README.md`)"


def test_links_to_result_folders_go_to_their_page():
    out = rewrite_outside_links("[Table 14](table14_warm_start/), [pushes](pushes/)", "experiments/warm_start.md", DOCS)
    assert (DOCS / "experiments" / "pushes" / "report.md").is_file()
    assert "[pushes](pushes/report.md)" in out
    page = "[Table 14](table14_warm_start/table.md)" if (DOCS / "experiments/table14_warm_start/table.md").is_file() \
        else "Table 14 (`docs/experiments/table14_warm_start/`)"
    assert page in out


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings") is None,
                    reason="the docs extra is not installed (pip install -e '.[docs]'; `make test` installs it)")
def test_the_site_builds_strict(tmp_path):
    site = tmp_path / "site"
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=REPO,
                         capture_output=True, text=True, timeout=300, check=False,
                         env={**os.environ, "PYTHONPATH": str(REPO), "NO_MKDOCS_2_WARNING": "1"})
    problems = [line for line in run.stderr.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert run.returncode == 0 and not problems, "\n".join(problems) or run.stderr[-3000:]
    # the API pages hold the docstrings: a reward term's and the env's, with their signatures
    mdp = (site / "api" / "mdp.html").read_text()
    assert "track_lin_vel_xy" in mdp and "height_scan" in mdp
    assert "check_actions" in (site / "api" / "env.html").read_text()
    for page in ("index.html", "install.html", "workflow.html", "tasks/base.html", "tutorials/index.html"):
        assert (site / page).is_file(), page


LONG_USAGE_PAGES = {"env.md", "mpc.md"}
"""Usage pages still over the limit: each holds measurements or history that belong on a report page (a split
like train.md's and benchmarks.md's); this set only shrinks."""


def test_usage_pages_stay_short():
    """Every page of the site's "Getting started" and "Usage" sections is at most 300 lines: how to use a command
    and its current figures; studies and history go to the "Reports" section."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    _Loader.add_multi_constructor("tag:yaml.org,2002:python/", lambda *a: None)
    nav = yaml.load((REPO / "mkdocs.yml").read_text(), Loader=_Loader)["nav"]
    usage = [page for section in nav if isinstance(section, dict)
             for title, entries in section.items() if title in ("Getting started", "Usage")
             for entry in entries for page in entry.values()]
    assert {"train.md", "benchmarks.md", "install.md", "workflow.md"} <= set(usage)
    long = {p: n for p in usage if (n := len((DOCS / p).read_text().splitlines())) > 300}
    assert set(long) <= LONG_USAGE_PAGES, {p: n for p, n in long.items() if p not in LONG_USAGE_PAGES}
    assert all(p in usage for p in LONG_USAGE_PAGES)
