"""play: the zero action (feed-forward trot) produces a trot in the gait trace and writes the plots."""

from __future__ import annotations

import numpy as np

from dls_quadruped.learning import play


def test_play_writes_plots_and_trot_contacts(tmp_path):
    out = play.main(["--task", "base", "--seconds", "1.0", "--num-envs", "2", "--out", str(tmp_path), "--no-video"])
    assert (out / "tracking.png").is_file() and (out / "gait.png").is_file()
    trace = np.load(out / "play.npz")
    c = trace["contact"]
    assert c.shape == (50, 4) and trace["command"].shape == (50, 3)
    # trot: diagonal pairs (FL, RR) and (FR, RL) agree most of the time, the two pairs mostly differ
    assert (c[:, 0] == c[:, 3]).mean() > 0.7 and (c[:, 1] == c[:, 2]).mean() > 0.7
    assert (c[:, 0] != c[:, 1]).mean() > 0.3
