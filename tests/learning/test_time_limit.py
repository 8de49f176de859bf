"""``train --time-limit``: a run that must fit a short job stops cleanly before its limit, with its checkpoint,
curve rows and exported policy, and ``--resume`` continues it bit for bit (issue 52, item 6).

The clock is replaced by a counter that advances 100 s per reading, so the stop does not depend on how fast
this machine trains: the deadline reads it once at the start and the runner once per iteration.
"""

from __future__ import annotations

import itertools

import pytest

from dls_quadruped.learning import time_limit, train
from dls_quadruped.learning.runner import checkpoints, read_checkpoint
from dls_quadruped.learning.time_limit import Deadline
from tests.learning.test_resume_from import differences


@pytest.fixture
def fake_clock(monkeypatch):
    ticks = itertools.count(0.0, 100.0)  # start 0; the runner's own start 100; iteration ends 200, 300, ...
    monkeypatch.setattr(time_limit, "clock", lambda: next(ticks))


def test_deadline_keeps_room_for_two_iterations_and_the_reserve(monkeypatch):
    monkeypatch.setattr(time_limit, "clock", lambda: 0.0)
    d = Deadline(100.0, reserve_s=10.0)  # started at 0
    assert not d.stop_after(19.0, now=50.0)  # 50 s left >= 2 * 19 + 10 = 48
    assert d.stop_after(21.0, now=50.0)      # 50 s left < 2 * 21 + 10 = 52
    assert d.left(now=30.0) == 70.0


def test_time_limit_stops_saves_exports_and_resume_is_bit_exact(fake_clock, tmp_path, write_task, train_args, capsys):
    task = write_task(tmp_path)
    # uninterrupted: 3 iterations, no limit (the fake clock is read but never stops it)
    full = train.main(train_args(task, tmp_path / "full", "--iterations", "3", "--seed", "7"))
    # limited: the deadline reads 0 at its start, the runner 100 at its own, iterations end at 200, 300, ...
    limited = tmp_path / "limited"
    run_dir = train.main(train_args(task, limited, "--iterations", "3", "--seed", "7", "--time-limit", "450"))
    out = capsys.readouterr().out
    # the runner's clock reading at its start was 100, iteration 0 ended at 200 (100 s): 250 left >= 220, go on;
    # iteration 1 ended at 300: 150 left < 220: stop after iteration 1
    assert "time limit (450 s) reached after iteration 1" in out, out[-2000:]
    assert max(checkpoints(run_dir))[0] == 1
    assert (run_dir / "exported" / "policy.pt2").is_file()
    assert list(run_dir.glob("events.out.tfevents.*")), "no curve rows"
    # --resume continues with iteration 2 and gives the uninterrupted run's checkpoint bit for bit
    train.main(train_args(task, limited, "--iterations", "1", "--resume"))
    want, got = read_checkpoint(full / "model_2.pt"), read_checkpoint(run_dir / "model_2.pt")
    assert got["iter"] == 2
    assert differences(want, got) == []
    # not vacuous: iteration 2 moved the weights
    assert ".actor_state_dict.mlp.0.weight" in differences(read_checkpoint(full / "model_1.pt"), want)


def test_time_limit_must_be_positive(tmp_path, write_task, train_args, capsys):
    with pytest.raises(SystemExit) as exc:
        train.parse_args(train_args(write_task(tmp_path), tmp_path / "run", "--time-limit", "0"))
    assert exc.value.code == 2
    assert "--time-limit" in capsys.readouterr().err
