"""The commit and the state of the tree a result file records (``eval.provenance``), in temporary git repositories."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from dls_quadruped.eval import provenance as prov


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout.strip()


@pytest.fixture
def repo(tmp_path, monkeypatch):
    """A repository with one committed file; git may not look above tmp_path for another repository."""
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))
    monkeypatch.delenv("DLS_GIT_COMMIT", raising=False)
    monkeypatch.delenv("DLS_GIT_DIRTY", raising=False)
    r = tmp_path / "repo"
    r.mkdir()
    git(r, "init", "-q")
    git(r, "config", "user.email", "t@t")
    git(r, "config", "user.name", "t")
    (r / "a.py").write_text("x = 1\n")
    git(r, "add", "a.py")
    git(r, "commit", "-q", "-m", "first")
    return r


def test_a_clean_tree_records_its_full_commit_and_is_not_dirty(repo, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the working directory is not the repository: git is asked in the repository
    p = prov.provenance(repo)
    assert p == {"git_commit": git(repo, "rev-parse", "HEAD"), "git_dirty": False, "uncommitted": []}
    assert len(p["git_commit"]) == 40


def test_an_edited_tracked_file_makes_the_tree_dirty_and_an_untracked_one_does_not(repo):
    (repo / "b.py").write_text("new, untracked\n")
    assert prov.provenance(repo)["git_dirty"] is False
    (repo / "a.py").write_text("x = 2\n")
    p = prov.provenance(repo)
    assert p["git_dirty"] is True and p["uncommitted"] == ["M a.py"]
    git(repo, "commit", "-q", "-am", "second")
    p2 = prov.provenance(repo)
    assert p2["git_dirty"] is False and p2["git_commit"] != p["git_commit"]


def test_a_copy_without_history_says_why_and_takes_the_commit_from_the_environment(repo, tmp_path, monkeypatch):
    copy = tmp_path / "frozen"
    copy.mkdir()
    (copy / "a.py").write_text("x = 1\n")  # a copy of the tree without .git, as the unknown-commit runs were
    p = prov.provenance(copy)
    assert p["git_commit"] == "unknown" and p["git_dirty"] is None
    assert "not a git repository" in p["git_error"] and str(copy) in p["git_error"]
    monkeypatch.setenv("DLS_GIT_COMMIT", git(repo, "rev-parse", "HEAD"))
    monkeypatch.setenv("DLS_GIT_DIRTY", "1")
    p = prov.provenance(copy)
    assert p["git_commit"] == git(repo, "rev-parse", "HEAD") and p["git_dirty"] is True
    assert p["git_commit_from"] == "DLS_GIT_COMMIT"


def test_by_default_the_checkout_of_the_package_is_asked_whatever_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    try:
        head = git(prov.CHECKOUT, "rev-parse", "HEAD")
    except subprocess.CalledProcessError:
        pytest.skip("this copy of the tree has no git history")
    assert prov.provenance()["git_commit"] == head
