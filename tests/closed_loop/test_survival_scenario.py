"""The eval suite's survival scenarios in the closed loop (issue 27 item 3): every robot of episode e
meets what the eval suite's env e meets (same command, terrain tile and row, push timer and the same
scheduled push, wrench and friction draws), for every sampler seed; a controller runs there and its
summary gives survival per terrain type and row; a blind MPC plans on the ground its feet stand on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from dls_quadruped.closed_loop.controllers import ControllerConfig
from dls_quadruped.closed_loop.episodes import commands, make_env, run_controllers
from dls_quadruped.closed_loop.metrics import summarize
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.eval import survival as SV
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.eval.sweep import place_on_rows
from dls_quadruped.eval.velocity_tracking import simple_commands
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.inputs import stance_ground_z

REPO = Path(__file__).resolve().parents[2]
E = 8  # > 6 columns: the episodes reach a second row


def _eval_env(scenario: str) -> LocomotionEnv:
    """The env the eval suite builds for ``scenario`` (``survival._evaluate`` / ``sweep.run``)."""
    rows, hard, strength = (SV.ROWS, SV.HARD, SV.STRENGTH) if scenario == "survival" else \
        (SV.SWEEP_ROWS, 0.0, SV.SWEEP_STRENGTH)
    opts = EvalOptions(episodes=E, seed=0, num_workers=0, episode_length_s=2.0)
    task = SV.survival_task(simple_commands(E, 0), opts, rows, hard, strength)
    env = LocomotionEnv(task, num_envs=E, seed=0, verbose=False)
    place_on_rows(env, SV.start_rows(E, len(task.data["terrain"]["types"]), rows))
    return env


def _draws(env, ids) -> dict:
    ids = torch.as_tensor(ids)
    return {s: env.schedule.uniform(ids, (3,), -1.0, 1.0, stream=s)
            for s in ("push_robot", "external_wrench", "randomize_friction")}


@pytest.mark.parametrize("scenario", ["survival", pytest.param("survival_sweep", marks=pytest.mark.slow)])
def test_every_sampler_seed_meets_the_eval_suites_episode(scenario: str) -> None:
    ref = _eval_env(scenario)
    ours = make_env(commands(E, 0, None), 2.0, seed=0, num_workers=0, replicas=2, scenario=scenario)
    try:
        both = torch.arange(2 * E) % E  # robot s E + e plays episode e
        for name in ("terrain_types", "terrain_levels"):
            torch.testing.assert_close(getattr(ours.scene, name), getattr(ref.scene, name)[both])
        torch.testing.assert_close(ours.command_manager.command, ref.command_manager.command[both])
        torch.testing.assert_close(ours.state.base_pos_w[:, :2], ref.state.base_pos_w[both, :2])
        for name, timer in ref.event_manager.timers.items():
            torch.testing.assert_close(ours.event_manager.timers[name], timer[both])
        assert "push" in ref.event_manager.timers
        a, b = _draws(ours, torch.arange(2 * E)), _draws(ref, both)
        for stream in a:
            torch.testing.assert_close(a[stream], b[stream])
        rows = ours.scene.terrain_levels.cpu().numpy()
        assert len(np.unique(rows)) > 1  # the episodes spread over the scenario's rows
    finally:
        ours.close()
        ref.close()


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_a_blind_mpc_runs_the_survival_task_with_survival_per_row() -> None:
    cfg = ControllerConfig("naive_warm_start", sampler=SamplerConfig(num_samples=300), ground="stance_feet")
    traces = run_controllers([cfg], commands(E, 0, None), 0.3, seed=0, num_workers=0, scenario="survival")
    s = summarize(traces["naive_warm_start"])
    assert [r["group"] for r in s["survival_per_row"]] == list(range(SV.ROWS))
    assert sum(r["robots"] for r in s["survival_per_row"]) == E
    assert sum(r["robots"] for r in s["survival_per_type"]) == E
    assert np.isfinite(traces["naive_warm_start"].rollout_cost).any()


def test_stance_ground_is_the_stance_feet_height() -> None:
    """Mean height of the commanded stance feet less the foot radius (all four with none in stance)."""
    import dataclasses

    from dls_quadruped.robots.aliengo import constants as C

    env = make_env(commands(2, 0, None), 0.2, seed=0, num_workers=0)
    try:
        feet = env.state.foot_pos_w.clone()
        feet[..., 2] = C.FOOT_RADIUS + torch.tensor([[0.10, 0.00, 0.02, 0.30], [0.05, 0.07, 0.09, 0.11]])
        contact = torch.tensor([[0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
        state = dataclasses.replace(env.state, foot_pos_w=feet, contact_cmd=contact)
        torch.testing.assert_close(stance_ground_z(state), torch.tensor([0.01, 0.08]))
    finally:
        env.close()
