"""Choosing a thesis-5.3 run's policy on validation episodes: the objective is the Table-4 reward plus W times the
trajectory cost the probe reads (two computations of c: the reward manager's term and the probe), ties go to the
later candidate, the chosen checkpoint exports to a student program whose outputs are the actor's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.eval.velocity_tracking import simple_commands
from dls_quadruped.learning.policy_file import load_module
from experiments import mpc_cost_select as S

REPO = Path(__file__).resolve().parents[2]

PARAMS = load_task(S.TASK).data["rewards"][S.TERM]["params"]
STUDENT = REPO / S.STUDENT


def test_objective_task_adds_the_term_only_for_a_nonzero_weight():
    opts = EvalOptions(episodes=2, seed=3, num_workers=0)
    cmds = simple_commands(2, 3)
    with_term = S.objective_task(cmds, opts, -0.05).data["rewards"]
    without = S.objective_task(cmds, opts, 0.0).data["rewards"]
    assert with_term[S.TERM]["weight"] == -0.05
    assert with_term[S.TERM]["params"] == PARAMS
    assert S.TERM not in without
    assert set(with_term) - {S.TERM} == set(without)  # the rest is the evaluation's Table-4 reward


def test_the_objective_moves_by_w_times_the_probed_cost():
    """Per episode, objective(W) - objective(0) = W x mean c: the reward manager's term against the probe's c."""
    opts = EvalOptions(episodes=2, seed=3, num_workers=0, episode_length_s=0.3)
    a = S.evaluate(STUDENT, -0.1, opts, PARAMS, num_steps=10)  # 10 of the episodes' 15 steps: none ends
    b = S.evaluate(STUDENT, 0.0, opts, PARAMS, num_steps=10)
    assert not any(a["per_episode"]["fell"])
    c = np.array(a["per_episode"]["c_mean"])
    assert np.all(c > 0.5)  # a walking student's horizon costs something (c ~ 8 while walking)
    np.testing.assert_allclose(b["per_episode"]["c_mean"], c, rtol=1e-6)  # c does not depend on the weight
    diff = np.array(a["per_episode"]["objective_per_step"]) - np.array(b["per_episode"]["objective_per_step"])
    # the probe reads c after each step from the (a_t, s_t) the action manager keeps; the reward computed it in the
    # step from the same pair
    np.testing.assert_allclose(diff, -0.1 * c, rtol=1e-5)


def test_ties_go_to_the_later_candidate():
    assert S.choose_latest([("a", 1.0), ("b", 2.0), ("c", 2.0), ("d", 1.5)]) == 2
    assert S.choose_latest([("a", float("nan")), ("b", 0.5)]) == 1
    with pytest.raises(Exception, match="no candidate has a finite"):
        S.choose_latest([("a", float("nan"))])


def test_a_student_program_is_exported_as_it_is(tmp_path):
    out = tmp_path / "chosen.pt2"
    S.export(STUDENT, out)
    obs = torch.randn(3, 259)
    got, want = load_module(out)(obs), load_module(STUDENT)(obs)
    got, want = (x[0] if isinstance(x, tuple) else x for x in (got, want))
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    assert out.with_suffix(".json").is_file()


def test_bad_arguments_are_refused(capsys):
    with pytest.raises(SystemExit):
        S.parse_args(["--weight", "0.1", "--extra", "x.pt", "--out", "o"])
    assert "--weight is a cost weight" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        S.parse_args(["--weight", "-0.1", "--out", "o"])
    assert "give --run or --extra" in capsys.readouterr().err


def test_networks_keep_the_chosen_checkpoints_actor_and_critic(tmp_path):
    from dls_quadruped.learning.checkpoint_file import load
    from dls_quadruped.learning.runner import read_checkpoint

    src = REPO / "docs" / "policies" / "base_recipe_networks.pt"  # any checkpoint with an actor and a critic
    out = tmp_path / "networks.pt"
    S.networks(src, out)
    got, want = load(out), read_checkpoint(src)  # the restricted unpickler of --init-from reads it
    for key in ("actor_state_dict", "critic_state_dict"):
        assert got[key].keys() == want[key].keys()
        for name, value in want[key].items():
            torch.testing.assert_close(got[key][name], value, rtol=0, atol=0)
    assert got["iter"] == want["iter"] and set(got) == {*want.keys() - {"infos"}, "infos"}
    S.networks(STUDENT, tmp_path / "none.pt")  # the student has no critic: nothing written
    assert not (tmp_path / "none.pt").exists()


def test_the_evaluation_refuses_a_run_name_it_cannot_weigh(tmp_path):
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "experiments.mpc_cost_eval", "--runs", "w0.2_s0", "--out",
                          str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode != 0 and "w0.2_s0" in res.stderr and "<w>_s<seed>" in res.stderr
    assert not (tmp_path / "cells").exists()  # refused before any cell ran
