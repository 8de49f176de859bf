"""7.1 experiments: each expert minus base on the same episodes (hand-made per-episode results)."""

from __future__ import annotations

import pytest

from dls_quadruped.eval.compare import paired_vs


def test_paired_vs_base_by_hand():
    cmd = [[0.5, 0.0, 0.0], [0.4, 0.1, 0.0], [0.3, -0.1, 0.2], [0.6, 0.0, -0.2]]
    results = {
        "base": {"per_episode": {"command": cmd, "fell": [False, True, False, True], "reward": [2.0, 1.0, 2.0, 1.5]}},
        "rough": {"per_episode": {"command": cmd, "fell": [False, False, False, True], "reward": [2.1, 1.2, 2.0, 1.6]}},
        "speed": {"per_episode": {"command": cmd[::-1], "fell": [False] * 4, "reward": [2.0] * 4}},  # other episodes
    }
    rows = {(r["policy"], r["metric"]): r for r in paired_vs(results)}
    assert set(rows) == {("rough - base", "survival [share]"), ("rough - base", "mean reward per step")}
    surv = rows[("rough - base", "survival [share]")]
    assert surv["mean difference"] == pytest.approx(0.25) and surv["episodes"] == 4  # one more survivor of four
    rew = rows[("rough - base", "mean reward per step")]
    assert rew["mean difference"] == pytest.approx(0.1)  # (0.1 + 0.2 + 0 + 0.1) / 4
    assert paired_vs({"rough": results["rough"]}) == []  # no base, nothing to pair with
