"""Every committed policy archive reads back whole: a ``.pt2`` (``torch.export``) or ``.pt`` zip whose bytes were
edited after saving (e.g. a text substitution run over a folder) fails its CRC here, not in the middle of an
experiment an hour later."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

POLICIES = Path(__file__).resolve().parents[2] / "docs" / "policies"
ARCHIVES = sorted(p for ext in ("*.pt2", "*.pt") for p in POLICIES.rglob(ext) if zipfile.is_zipfile(p))


def test_there_are_archives_to_check():
    assert len([p for p in ARCHIVES if p.suffix == ".pt2"]) >= 10, ARCHIVES


@pytest.mark.parametrize("path", ARCHIVES, ids=lambda p: str(p.relative_to(POLICIES)))
def test_a_committed_archive_is_intact(path: Path):
    with zipfile.ZipFile(path) as z:
        assert z.testzip() is None


def test_an_edited_archive_is_caught(tmp_path: Path):
    """The check itself: one byte removed from the middle of a committed student breaks the archive."""
    good = next(p for p in ARCHIVES if p.name == "student.pt2")
    data = good.read_bytes()
    bad = tmp_path / "student.pt2"
    bad.write_bytes(data[: len(data) // 2] + data[len(data) // 2 + 1:])
    with pytest.raises((zipfile.BadZipFile, OSError)), zipfile.ZipFile(bad) as z:
        assert z.testzip() is None
