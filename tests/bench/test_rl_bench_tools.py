"""Tools of the RL benchmark: stage timer and the learning-curve reader (TensorBoard -> CSV)."""

from __future__ import annotations

import csv
import time

import pytest
from torch.utils.tensorboard import SummaryWriter

from dls_quadruped.bench.rl_env import StageTimer
from dls_quadruped.viz.learning_curve import plot, read_run, write_csv


class _Obj:
    def work(self, x: int, sleep_s: float = 0.0) -> int:
        time.sleep(sleep_s)
        return 2 * x


def test_stage_timer_wraps_in_place_and_accumulates():
    obj, timer = _Obj(), StageTimer()
    timer.wrap(obj, "work", "stage")
    assert obj.work(3, sleep_s=0.02) == 6  # the wrapped call still returns the method's value
    obj.work(1, sleep_s=0.02)
    assert 0.04 <= timer.total["stage"] < 0.5
    timer.enabled = False
    before = timer.total["stage"]
    obj.work(1, sleep_s=0.02)
    assert timer.total["stage"] == before  # disabled: nothing added
    assert _Obj().work(2) == 4  # other instances are untouched


def test_learning_curve_reads_scalars_and_later_event_file_wins(tmp_path):
    w = SummaryWriter(log_dir=str(tmp_path))
    for it in range(3):
        w.add_scalar("Train/mean_reward", 1.0 + it, it)
        w.add_scalar("Train/mean_episode_length", 10.0 * it, it)
        w.add_scalar("Episode_Metric/lin_vel_xy_error", 0.5 - 0.1 * it, it)
        w.add_scalar("Policy/mean_std", 1.0 + 0.25 * it, it)
    w.close()
    time.sleep(1.1)  # event file names carry the second: the resumed run's file sorts after
    w = SummaryWriter(log_dir=str(tmp_path))
    w.add_scalar("Train/mean_reward", 7.0, 2)  # a resumed run re-logs iteration 2
    w.close()
    rows = read_run(tmp_path)
    assert [r["iteration"] for r in rows] == [0, 1, 2]
    assert [r["mean_reward"] for r in rows] == pytest.approx([1.0, 2.0, 7.0])
    assert rows[1]["lin_vel_xy_error"] == pytest.approx(0.4)
    assert rows[2]["action_std"] == pytest.approx(1.5) and "terrain_level" not in rows[2]
    write_csv(rows, tmp_path / "c.csv")
    with open(tmp_path / "c.csv") as fh:
        table = list(csv.DictReader(fh))
    assert float(table[2]["mean_episode_length"]) == pytest.approx(20.0)
    assert table[0]["collection_s"] == ""  # missing scalars stay empty
    plot(rows, tmp_path / "c.png", "test")
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_learning_curve_without_events_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError, match="no TensorBoard scalars"):
        read_run(tmp_path)
