"""PPO in the MPC's horizon space from the DAgger student: the actor built from the student outputs what the student
outputs, ``base_mpc_cost`` trains from it (2 iterations, 4 robots, episodes of 0.5 s), and an actor exports back to a
student program the closed loop accepts."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch

from dls_quadruped.cli import UserError
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning import train
from dls_quadruped.learning.runner import (
    AtomicOnPolicyRunner,
    read_checkpoint,
    runner_config,
)
from dls_quadruped.learning.student import load_student
from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.horizon import TERM_NAMES
from experiments import mpc_cost_init

REPO = Path(__file__).resolve().parents[2]

SHORT = ["--set", "env.episode_length_s=0.5", "--set", "scene.num_workers=0"]


@pytest.fixture(scope="module")
def networks(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("init") / "student_networks.pt"
    mpc_cost_init.main(["--out", str(out)])
    return out


def test_the_actor_outputs_the_students_horizon(networks):
    task = load_task("base_mpc_cost", overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=4, verbose=False, seed=2)
    try:
        runner = AtomicOnPolicyRunner(env, runner_config(task.data["agent"], 1, 0), log_dir=None, device="cpu")
        runner.init_networks(read_checkpoint(networks), str(networks))
        obs, _ = env.reset()
        for _ in range(5):  # states away from the reset pose
            obs, *_ = env.step(torch.zeros(4, 64))
        student, _ = load_student(mpc_cost_init.STUDENT)
        with torch.no_grad():
            actor = runner.alg.get_policy()(obs)
            expected = student(obs["policy"])
        torch.testing.assert_close(actor, expected, rtol=1e-5, atol=1e-5)
        assert float(expected[:, 16::4].abs().max()) > 0.1  # theta_-1 of F (x10 output scale) is in the check
    finally:
        env.close()


def test_std_is_the_experts_per_encoded_scalar():
    std28 = torch.arange(28, dtype=torch.float32)
    std = mpc_cost_init.expert_std_per_entry(std28, EncodingConfig("first", "spline", 10))
    assert std.shape == (64,)
    torch.testing.assert_close(std[:16], std28[:16])  # f, d, first p
    torch.testing.assert_close(std[16:20], torch.full((4,), 16.0))  # F_x of FL: its 4 spline parameters
    torch.testing.assert_close(std[60:64], torch.full((4,), 27.0))


def test_a_student_of_another_encoding_is_refused():
    with pytest.raises(UserError, match=r"does not encode the task's actions.horizon: F 'spline' \(task: 'discrete'\)"):
        mpc_cost_init.student_networks(mpc_cost_init.STUDENT, mpc_cost_init.CRITIC,
                                       EncodingConfig("first", "discrete", 10), 0.02)


def test_ppo_trains_two_iterations_from_the_student(networks, tmp_path):
    run = tmp_path / "run"
    train.main(["--task", "base_mpc_cost", "--num-envs", "4", "--iterations", "2", "--run-dir", str(run),
                "--init-from", str(networks), "--update-threads", "1", *SHORT])
    last = read_checkpoint(run / "model_1.pt")
    assert last["num_actions"] == 64
    first = read_checkpoint(networks)["actor_state_dict"]["mlp.6.weight"]
    assert not torch.equal(last["actor_state_dict"]["mlp.6.weight"], first)  # PPO moved the student's last layer
    assert (run / "exported" / "policy.pt2").is_file()
    from experiments import mpc_cost_curve

    curve = mpc_cost_curve.main([str(run), "--csv", str(tmp_path / "curve.csv")])
    rows = list(csv.DictReader(curve.open()))
    assert [int(r["iteration"]) for r in rows] == [0, 1]
    split = sum(float(rows[-1][f"mpc_trajectory_cost/{t}"]) for t in TERM_NAMES)
    assert split == pytest.approx(float(rows[-1]["mpc_trajectory_cost"]), rel=1e-3)  # logged split sums to the term
    assert float(rows[-1]["mpc_trajectory_cost"]) < 0
    assert (tmp_path / "curve.png").is_file()


def test_export_back_to_a_student_round_trips(networks, tmp_path):
    """init (student -> actor) then export (actor -> student program): the program outputs the original student's
    horizon and its metadata passes the closed loop's encoding check."""
    from dls_quadruped.mpc.config import SamplerConfig
    from dls_quadruped.mpc.warm_start import check_student_encoding
    from experiments import mpc_cost_export

    out = mpc_cost_export.main([str(networks), "--out", str(tmp_path / "back.pt2")])
    back, meta = load_student(out)
    check_student_encoding(meta, SamplerConfig())  # first-spline, H = 10, dt = 0.02 s
    original, _ = load_student(mpc_cost_init.STUDENT)
    obs = read_checkpoint(mpc_cost_init.CRITIC)["critic_state_dict"]["obs_normalizer._mean"].expand(6, -1).clone()
    obs += 0.1 * torch.randn(obs.shape, generator=torch.Generator().manual_seed(0))  # states near the data's mean
    with torch.no_grad():
        torch.testing.assert_close(back(obs), original(obs), rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(back.first_action(obs), original.first_action(obs), rtol=1e-4, atol=1e-4)


def test_an_actor_with_its_own_normaliser_exports_with_it():
    """A run from scratch keeps rsl-rl's running normaliser: the exported program computes the actor's mean,
    mlp(normaliser(obs)), written out here with rsl-rl's own modules."""
    from rsl_rl.modules import MLP, EmpiricalNormalization

    from dls_quadruped.mpc.config import EncodingConfig
    from experiments.mpc_cost_export import student_from_actor

    enc = EncodingConfig("first", "spline", 10)
    gen = torch.Generator().manual_seed(1)
    norm = EmpiricalNormalization(259)
    norm.train()
    norm(3.0 + 2.0 * torch.randn(64, 259, generator=gen))  # running stats far from (0, 1)
    norm.eval()
    mlp = MLP(259, 64, [32, 16], "elu")
    actor = {**{f"mlp.{k}": v for k, v in mlp.state_dict().items()},
             **{f"obs_normalizer.{k}": v for k, v in norm.state_dict().items()}}
    student = student_from_actor(actor, enc, 259)
    obs = 3.0 + 2.0 * torch.randn(5, 259, generator=gen)
    with torch.no_grad():
        torch.testing.assert_close(student(obs), mlp(norm(obs)), rtol=1e-5, atol=1e-5)
        assert not torch.allclose(student(obs), mlp(obs), atol=1e-2)  # the normaliser mattered
