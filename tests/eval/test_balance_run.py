"""The balance controller run as a controller of the env (``eval/balance_run.py``) is the loop it replaces: the
backend stepped by hand from ``home_state``, the same references each step, bit for bit."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from dls_quadruped.control.balance import BalanceController
from dls_quadruped.control.latent_action import (
    LatentActionConfig,
    clip,
    flat_ground,
    to_world,
)
from dls_quadruped.eval.balance_run import _yaw, run_balance
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend


def _by_hand(n: int, stand: int, trot: int, cmd: tuple, seed: int, noise: float, yaw: torch.Tensor) -> np.ndarray:
    """(T, n, 19) qpos of the balance controller on the backend alone, 2 physics steps per action."""
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    ctrl, acfg = BalanceController(), LatentActionConfig()
    command = torch.tensor(cmd, dtype=torch.float64).expand(n, 3)
    out = []
    with make_backend("cpu", model, n, SimConfig(num_workers=0)) as sim:
        state = sim.reset(torch.arange(n), **home_state(n, seed, noise, yaw))
        for k in range(stand + trot):
            action, _ = clip(ctrl(state, command, stand=k < stand), acfg)
            p_td_w, F_w = to_world(action, state.base_pos_w.double(), _yaw(state), flat_ground, acfg)
            sim.set_references(action.f, action.d, p_td_w, F_w)
            state = sim.step(2)
            out.append(torch.cat([state.base_pos_w, state.base_quat_w, state.joint_pos], dim=1).numpy().copy())
    return np.asarray(out)


def test_the_env_controller_reproduces_the_backend_loop_bit_for_bit():
    yaw = torch.tensor([0.0, 2.0], dtype=torch.float64)
    run = run_balance(num_envs=2, stand_seconds=0.05, trot_seconds=0.7, cmd_vel_h=(0.3, 0.1, 0.2), seed=3,
                      joint_noise=0.04, yaw=yaw)
    expected = _by_hand(2, 5, 70, (0.3, 0.1, 0.2), 3, 0.04, yaw)  # a gait cycle: the summary needs it
    assert run.qpos.shape == expected.shape == (75, 2, 19)
    np.testing.assert_array_equal(run.qpos, expected)
    assert run.trotting.tolist() == [False] * 5 + [True] * 70
    np.testing.assert_allclose(run.time, 0.01 * np.arange(1, 76), rtol=1e-12)
    np.testing.assert_array_equal(run.base_height, expected[..., 2])
