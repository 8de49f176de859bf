"""Disk-backed FIFO dataset: cap, order, reopening after a simulated crash, corrupt directories."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from dls_quadruped.learning.dataset import DatasetError, DiskDataset


def rows(first: int, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Row r has obs (r, r, r) and label (-r, r)."""
    r = torch.arange(first, first + n, dtype=torch.float32)
    return r[:, None].expand(n, 3).clone(), torch.stack([-r, r], dim=1)


def test_cap_keeps_newest_rows_in_insertion_order(tmp_path):
    ds = DiskDataset.create(tmp_path / "d", 3, 2, capacity=10)
    for first, n in ((0, 4), (4, 4), (8, 5), (13, 1)):  # 14 rows through a cap of 10
        ds.append(*rows(first, n))
    obs, labels = ds.ordered()
    assert len(ds) == 10 and ds.total_written == 14
    assert obs[:, 0].tolist() == list(range(4, 14))  # the 4 oldest went first (FIFO)
    torch.testing.assert_close(labels, rows(4, 10)[1])
    ds.append(*rows(100, 25))  # more than the cap in one go: the newest 10 stay
    assert ds.ordered()[0][:, 0].tolist() == list(range(115, 125))


def test_reopen_gives_the_same_rows(tmp_path):
    ds = DiskDataset.create(tmp_path / "d", 3, 2, capacity=6, meta={"enc": "first-spline"})
    ds.append(*rows(0, 9))
    again = DiskDataset.open(tmp_path / "d", meta={"enc": "first-spline"})
    assert len(again) == 6 and again.total_written == 9
    torch.testing.assert_close(again.ordered()[0], ds.ordered()[0])
    with pytest.raises(DatasetError, match="collected for"):
        DiskDataset.open(tmp_path / "d", meta={"enc": "discrete-discrete"})


@pytest.mark.parametrize("crash_at_commit", [1, 2])
def test_crash_during_append_keeps_every_committed_row(tmp_path, monkeypatch, crash_at_commit):
    """Kill between the writes of an append: the reopened dataset has only whole, committed rows."""
    ds = DiskDataset.create(tmp_path / "d", 3, 2, capacity=8)
    ds.append(*rows(0, 8))  # full
    calls = {"n": 0}
    real_commit = DiskDataset._commit

    def crashing_commit(self, **changes):
        calls["n"] += 1
        if calls["n"] == crash_at_commit:
            raise KeyboardInterrupt("killed")
        real_commit(self, **changes)

    monkeypatch.setattr(DiskDataset, "_commit", crashing_commit)
    with pytest.raises(KeyboardInterrupt):
        ds.append(*rows(100, 3))  # evicts rows 0-2 (commit 1), writes, commits (commit 2)
    monkeypatch.undo()
    again = DiskDataset.open(tmp_path / "d")
    obs, labels = again.ordered()
    if crash_at_commit == 1:  # killed before anything changed
        assert obs[:, 0].tolist() == list(range(8))
    else:  # eviction committed, new rows written but not committed: they are not counted
        assert obs[:, 0].tolist() == list(range(3, 8))
    torch.testing.assert_close(labels, torch.stack([-obs[:, 0], obs[:, 0]], dim=1))
    again.append(*rows(200, 4))  # and it goes on from there
    assert again.ordered()[0][:, 0].tolist()[-4:] == [200, 201, 202, 203]


def test_corrupt_or_missing_directory_is_named(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        DiskDataset.open(tmp_path / "nothing")
    DiskDataset.create(tmp_path / "d", 3, 2, capacity=4).append(*rows(0, 2))
    (tmp_path / "d" / "state.json").write_text("{not json")
    with pytest.raises(DatasetError, match="corrupt: unreadable state.json"):
        DiskDataset.open(tmp_path / "d")
    DiskDataset.create(tmp_path / "e", 3, 2, capacity=4)
    (tmp_path / "e" / "labels.npy").unlink()
    with pytest.raises(DatasetError, match="labels.npy is missing"):
        DiskDataset.open(tmp_path / "e")
    DiskDataset.create(tmp_path / "f", 3, 2, capacity=4)
    np.save(tmp_path / "f" / "obs.npy", np.zeros((4, 5), dtype=np.float32))
    with pytest.raises(DatasetError, match=r"obs.npy has shape \(4, 5\)"):
        DiskDataset.open(tmp_path / "f")
    state = json.loads((tmp_path / "f" / "state.json").read_text())
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "state.json").write_text(json.dumps({**state, "size": 9}))
    with pytest.raises(DatasetError, match="size 9 for capacity 4"):
        DiskDataset.open(tmp_path / "g")
    with pytest.raises(DatasetError, match="already holds"):
        DiskDataset.create(tmp_path / "d", 3, 2, capacity=4)


def test_minibatches_visit_every_row_once(tmp_path):
    ds = DiskDataset.create(tmp_path / "d", 3, 2, capacity=50)
    ds.append(*rows(0, 70))  # wrapped ring
    gen = torch.Generator().manual_seed(0)
    batches = list(ds.minibatches(8, gen, chunk=16))
    seen = torch.cat([o[:, 0] for o, _ in batches])
    assert sorted(seen.tolist()) == list(range(20, 70))
    assert all(len(o) <= 8 for o, _ in batches)
    for o, lab in batches:  # rows stay paired
        torch.testing.assert_close(lab[:, 1], o[:, 0])
