"""Disk-backed, capped FIFO dataset of (observation, label) rows (thesis 5.2, Table 7 cap 800 000).

The thesis kept its dataset in GPU memory and names that as a limit (7.3.5); this one lives on
disk and can exceed RAM. A dataset directory holds

    obs.npy      (capacity, obs_dim)   float32, NumPy's .npy format, memory-mapped (open_memmap)
    labels.npy   (capacity, label_dim) float32
    state.json   {capacity, obs_dim, label_dim, start, size, total_written, meta}

The arrays are a ring buffer: valid rows are ``(start + arange(size)) % capacity`` in insertion
order; appending beyond the cap drops the oldest rows (FIFO). ``state.json`` is replaced
atomically (tmp + ``os.replace``) and only describes rows whose bytes are already written, so a
process killed at any point reopens with every committed row intact: an append first commits the
eviction of the rows it will overwrite, then writes them, then commits them.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

STATE = "state.json"
FORMAT = 1


class DatasetError(ValueError):
    """A dataset directory is missing, corrupt or does not fit what is asked of it."""


def _write_json_atomic(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


class DiskDataset:
    """Use :meth:`create` or :meth:`open`; ``append`` rows, ``minibatches`` to train."""

    def __init__(self, path: Path, obs: np.memmap, labels: np.memmap, state: dict):
        self.path, self._obs, self._labels, self._state = Path(path), obs, labels, state

    # ------------------------------------------------------------------ construction
    @classmethod
    def create(cls, path: str | Path, obs_dim: int, label_dim: int, capacity: int, meta: dict | None = None
               ) -> DiskDataset:
        """New empty dataset in ``path`` (which must not hold one already)."""
        path = Path(path)
        if (path / STATE).exists():
            raise DatasetError(f"{path} already holds a dataset; open it instead")
        if capacity < 1 or obs_dim < 1 or label_dim < 1:
            raise DatasetError(f"capacity, obs_dim, label_dim must be >= 1, got {capacity}, {obs_dim}, {label_dim}")
        path.mkdir(parents=True, exist_ok=True)
        # sparse files: disk is used only where rows are written
        obs = np.lib.format.open_memmap(path / "obs.npy", mode="w+", dtype=np.float32, shape=(capacity, obs_dim))
        labels = np.lib.format.open_memmap(path / "labels.npy", mode="w+", dtype=np.float32,
                                           shape=(capacity, label_dim))
        state = {"format": FORMAT, "capacity": int(capacity), "obs_dim": int(obs_dim), "label_dim": int(label_dim),
                 "start": 0, "size": 0, "total_written": 0, "meta": meta or {}}
        _write_json_atomic(path / STATE, state)
        return cls(path, obs, labels, state)

    @classmethod
    def open(cls, path: str | Path, meta: dict | None = None) -> DiskDataset:
        """Reopen a dataset (e.g. after a crash). If ``meta`` is given it must equal the stored one.

        Raises:
            DatasetError: missing directory or files, unreadable state, arrays of the wrong shape,
                or other metadata (another encoding).
        """
        path = Path(path)
        if not path.is_dir():
            raise DatasetError(f"dataset directory {path} not found")
        try:
            state = json.loads((path / STATE).read_text())
            capacity, size, start = int(state["capacity"]), int(state["size"]), int(state["start"])
            obs_dim, label_dim = int(state["obs_dim"]), int(state["label_dim"])
        except FileNotFoundError:
            raise DatasetError(f"dataset {path} is corrupt: {STATE} is missing") from None
        except (ValueError, KeyError, TypeError) as err:
            raise DatasetError(f"dataset {path} is corrupt: unreadable {STATE} ({type(err).__name__}: {err})") from None
        if not (0 <= size <= capacity and 0 <= start < capacity):
            raise DatasetError(f"dataset {path} is corrupt: start {start}, size {size} for capacity {capacity}")
        arrays = []
        for name, dim in (("obs.npy", obs_dim), ("labels.npy", label_dim)):
            try:
                arr = np.load(path / name, mmap_mode="r+")
            except FileNotFoundError:
                raise DatasetError(f"dataset {path} is corrupt: {name} is missing") from None
            except (ValueError, OSError) as err:
                raise DatasetError(f"dataset {path} is corrupt: {name} unreadable ({err})") from None
            if arr.shape != (capacity, dim) or arr.dtype != np.float32:
                raise DatasetError(f"dataset {path} is corrupt: {name} has shape {arr.shape} {arr.dtype}, "
                                   f"{STATE} says ({capacity}, {dim}) float32")
            arrays.append(arr)
        if meta is not None and state.get("meta") != meta:
            raise DatasetError(f"dataset {path} was collected for {state.get('meta')}, not {meta}")
        return cls(path, arrays[0], arrays[1], state)

    # ------------------------------------------------------------------ properties
    @property
    def capacity(self) -> int:
        return self._state["capacity"]

    @property
    def total_written(self) -> int:
        """Rows ever appended (including those dropped by the cap)."""
        return self._state["total_written"]

    @property
    def meta(self) -> dict:
        return self._state["meta"]

    def __len__(self) -> int:
        return self._state["size"]

    def positions(self) -> np.ndarray:
        """(size,) ring positions of the valid rows, oldest first."""
        return (self._state["start"] + np.arange(len(self))) % self.capacity

    # ------------------------------------------------------------------ writing
    def _commit(self, **changes) -> None:
        self._state.update(changes)
        _write_json_atomic(self.path / STATE, self._state)

    def append(self, obs: torch.Tensor | np.ndarray, labels: torch.Tensor | np.ndarray) -> None:
        """Append rows (N, obs_dim), (N, label_dim); beyond the cap the oldest rows go (FIFO)."""
        obs = np.asarray(torch.as_tensor(obs, dtype=torch.float32).cpu())
        labels = np.asarray(torch.as_tensor(labels, dtype=torch.float32).cpu())
        expected_labels = (len(obs), self._state["label_dim"])
        if obs.ndim != 2 or obs.shape[1] != self._state["obs_dim"] or labels.shape != expected_labels:
            raise DatasetError(f"rows must be (N, {self._state['obs_dim']}) and (N, {self._state['label_dim']}), "
                               f"got {obs.shape} and {labels.shape}")
        n_in = len(obs)
        if n_in == 0:
            return
        cap = self.capacity
        if n_in > cap:  # only the newest cap rows can stay
            obs, labels = obs[-cap:], labels[-cap:]
        n = len(obs)
        start, size = self._state["start"], self._state["size"]
        evict = max(0, size + n - cap)
        if evict:  # 1. forget the rows about to be overwritten
            start, size = (start + evict) % cap, size - evict
            self._commit(start=start, size=size)
        pos = (start + size + np.arange(n)) % cap  # 2. write
        self._obs[pos] = obs
        self._labels[pos] = labels
        self._obs.flush()
        self._labels.flush()
        self._commit(size=size + n, total_written=self._state["total_written"] + n_in)  # 3. commit

    # ------------------------------------------------------------------ reading
    def rows(self, positions: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """(obs, labels) float32 tensors of the given ring positions."""
        positions = np.asarray(positions)
        return torch.from_numpy(np.array(self._obs[positions])), torch.from_numpy(np.array(self._labels[positions]))

    def ordered(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Every valid row, oldest first (loads them all: for small sets and tests)."""
        return self.rows(self.positions())

    def minibatches(self, batch_size: int, generator: torch.Generator, chunk: int = 65_536, limit: int | None = None
                    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """One shuffled pass in mini-batches (the last, smaller one included); with ``limit``, a pass
        over a random subset of ``limit`` rows (the first ``limit`` of the shuffled order).

        Rows are read from disk ``chunk`` at a time (sorted positions, so reads are mostly
        sequential), each chunk being a random subset; RAM use is bounded by the chunk.
        """
        order = self.positions()[torch.randperm(len(self), generator=generator).numpy()]
        if limit is not None:
            order = order[:limit]
        for c in range(0, len(order), chunk):
            part = np.sort(order[c:c + chunk])
            obs, labels = self.rows(part)
            perm = torch.randperm(len(part), generator=generator)
            for b in range(0, len(part), batch_size):
                idx = perm[b:b + batch_size]
                yield obs[idx], labels[idx]
