"""The golden trajectories (``tests/golden/record.py``) are reproduced by today's code.

On the machine that recorded them (same CPU, flags and library versions) every array must be
bit-identical: a refactor that is not meant to change behaviour changes none of them. On another
machine floating-point paths differ (vector width, FMA), so only the short, smooth runs (env, rough
env and policy evaluation) are compared, within a tolerance; the MPC runs, whose argmin can flip on a
last-bit difference, are compared on the recording machine only.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.golden.record import HERE, fingerprint, record

GOLDEN = np.load(HERE / "trajectories.npz")
SAME_MACHINE = fingerprint() | {"torch_threads": 1} == json.loads((HERE / "fingerprint.json").read_text())
SMOOTH = ("env", "rough", "eval")


def _differences(new: dict, names: tuple[str, ...], exact: bool) -> list[str]:
    bad = []
    for key in GOLDEN.files:
        if key.split(".", 1)[0] not in names:
            continue
        a, b = GOLDEN[key], new[key]
        if a.shape != b.shape:
            bad.append(f"{key}: shape {b.shape}, golden {a.shape}")
        elif exact and not np.array_equal(a, b, equal_nan=True) or \
                not exact and not np.allclose(a, b, rtol=1e-3, atol=1e-4, equal_nan=True):
            bad.append(f"{key}: max |diff| {np.nanmax(np.abs(b.astype(float) - a.astype(float))):.3g}")
    return bad


@pytest.mark.skipif(not SAME_MACHINE, reason="golden trajectories were recorded on another machine "
                                             "(tests/golden/fingerprint.json); bit-identity is checked there")
def test_golden_trajectories_are_bit_identical():
    new = record()
    assert set(new) == set(GOLDEN.files)
    bad = _differences(new, tuple({k.split(".", 1)[0] for k in GOLDEN.files}), exact=True)
    assert not bad, ("behaviour changed (re-record with `python -m tests.golden.record` only if meant):\n"
                     + "\n".join(bad))


def test_smooth_golden_runs_agree_within_tolerance():
    new = record(SMOOTH)
    bad = _differences(new, SMOOTH, exact=False)
    assert not bad, "\n".join(bad)
