"""The model-based baseline run in the env (``closed_loop/baseline_run.py``: the ``naive_warm_start`` controller
sending world references) is the loop it replaces: the backend stepped by hand from ``home_state``, one solve's
world references per MPC period, bit for bit."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from dls_quadruped.closed_loop.baseline_run import run_baseline
from dls_quadruped.mpc.baseline import BaselineConfig, ModelBasedBaseline
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend

CFG = BaselineConfig(sampler=SamplerConfig(num_samples=64))


def test_the_env_controller_reproduces_the_backend_loop_bit_for_bit():
    run = run_baseline((0.4, 0.0, 0.1), seconds=0.06, num_robots=2, cfg=CFG, seed=5)
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    ctrl = ModelBasedBaseline(2, CFG, "cpu", 5)
    cmd = torch.tensor((0.4, 0.0, 0.1), dtype=torch.float32).expand(2, 3)
    qpos, cost = [], []
    with make_backend("cpu", model, 2, SimConfig(num_workers=0)) as sim:
        state = sim.reset(torch.arange(2), **home_state(2, 5, 0.0))
        for _ in range(6):
            result, _ = ctrl.step(state, cmd)
            sim.set_references(result.f, result.d, result.foot_target_w, result.force_w)
            state = sim.step(2)
            qpos.append(torch.cat([state.base_pos_w, state.base_quat_w, state.joint_pos], 1).numpy().copy())
            cost.append(result.best_cost.numpy().copy())
    assert run.qpos.shape == (6, 2, 19)
    np.testing.assert_array_equal(run.qpos, np.asarray(qpos))
    np.testing.assert_array_equal(run.best_cost, np.asarray(cost))
    np.testing.assert_allclose(run.time, 0.01 * np.arange(1, 7), rtol=1e-12)
    assert run.fallen.tolist() == [False, False]
