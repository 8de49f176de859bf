"""The code a result was computed with: the commit of the checkout and whether its tracked files differ from it.

Every result file of ``python -m dls_quadruped.eval`` and of ``experiments/`` carries :func:`provenance`'s keys:

- ``git_commit``: the full hash of ``HEAD``;
- ``git_dirty``: True when a tracked file differs from that commit (another person's edit in progress changes
  what runs; untracked files are not counted), None when unknown;
- ``uncommitted``: those files, as ``git status --short`` prints them.

Git is asked in the checkout this package was imported from, whatever the working directory. A copy of the tree
without its ``.git`` (a folder copied to freeze the code while others edit the checkout) has no history: there
``DLS_GIT_COMMIT`` (and ``DLS_GIT_DIRTY``, ``1`` or ``0``) name what the copy was made from, e.g.
``DLS_GIT_COMMIT=$(git -C <checkout> rev-parse HEAD)``; a copy made with ``git worktree add --detach`` needs
neither. Without either, ``git_commit`` is ``"unknown"`` and ``git_error`` says why (git's own message).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[2]
"""The folder above the package: the checkout (or copy) the running code was imported from."""


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True,
                          timeout=30).stdout


def provenance(repo: Path | None = None) -> dict:
    """``{"git_commit", "git_dirty", "uncommitted"}`` of ``repo`` (default :data:`CHECKOUT`), plus ``git_error``
    where git could not tell (see the module's docstring for the environment variables that stand in)."""
    repo = CHECKOUT if repo is None else Path(repo)
    try:
        commit = _git(repo, "rev-parse", "--verify", "HEAD").strip()
        changed = [line.strip() for line in _git(repo, "status", "--short", "--untracked-files=no").splitlines()
                   if line.strip()]
        return {"git_commit": commit, "git_dirty": bool(changed), "uncommitted": changed}
    except (OSError, subprocess.SubprocessError) as e:
        stderr = getattr(e, "stderr", None) or str(e)
        error = stderr.strip().splitlines()[0] if stderr.strip() else type(e).__name__
    env = os.environ.get("DLS_GIT_COMMIT", "").strip()
    dirty = {"1": True, "0": False}.get(os.environ.get("DLS_GIT_DIRTY", "").strip())
    out = {"git_commit": env or "unknown", "git_dirty": dirty, "uncommitted": None,
           "git_error": f"{repo}: {error}"}
    if env:
        out["git_commit_from"] = "DLS_GIT_COMMIT"
    return out
