"""Reset placement: no foot starts inside the terrain, whatever the reset's joint scale or the ground under
the feet; the nominal pose on flat ground is placed exactly as before. The analytic foot kinematics of the
reset are checked against MuJoCo's own."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp.events import foot_positions_b
from dls_quadruped.robots.aliengo import constants as C

CLEARANCE = 0.02  # reset_robot's default height - STANDING_BASE_HEIGHT


def test_foot_kinematics_match_mujoco():
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    lim = C.JOINT_RANGES
    sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in C.FOOT_NAMES]
    for _ in range(20):
        q = rng.uniform(lim[:, 0], lim[:, 1])
        data.qpos[:] = 0.0
        data.qpos[3] = 1.0  # base at the origin, identity orientation
        data.qpos[7:19] = q
        mujoco.mj_kinematics(model, data)
        ours = foot_positions_b(torch.as_tensor(q, dtype=torch.float64)[None])[0].numpy()
        np.testing.assert_allclose(ours, data.site_xpos[sites], atol=1e-9)


def _env(task: str, joint_scale, **terrain) -> LocomotionEnv:
    events = {"reset_robot": {"mode": "reset", "params": {"joint_scale": joint_scale}}}
    over = {"scene": {"num_workers": 0}, "events": events}
    if terrain:
        over["terrain"] = terrain
    return LocomotionEnv(load_task(task, overrides=over), num_envs=64, seed=3, verbose=False)


def _foot_clearance(env: LocomotionEnv) -> torch.Tensor:
    """(N, 4) foot sphere bottom above the terrain under its centre [m]."""
    feet = env.scene.sim.state.foot_pos_w
    ground = env.scene.terrain.height_at(feet[..., 0].float(), feet[..., 1].float()).double()
    return feet[..., 2] - C.FOOT_RADIUS - ground


def test_nominal_pose_on_flat_ground_is_placed_at_the_standing_height():
    env = _env("base", [1.0, 1.0])
    try:
        z = env.scene.sim.state.base_pos_w[:, 2]
        assert torch.all(z == torch.tensor(C.STANDING_BASE_HEIGHT + CLEARANCE, dtype=torch.float32).double())
        np.testing.assert_allclose(_foot_clearance(env).numpy(), CLEARANCE, atol=1e-6)
    finally:
        env.close()


def test_scaled_joints_start_with_every_foot_above_flat_ground():
    env = _env("base", [0.8, 1.2])
    try:
        gap = _foot_clearance(env)
        assert gap.min() > CLEARANCE - 1e-5  # before the fix: 3/4 of the robots had a foot up to 4 cm inside
        lowest = gap.min(dim=1).values
        z = env.scene.sim.state.base_pos_w[:, 2]
        raised = z > C.STANDING_BASE_HEIGHT + CLEARANCE + 1e-5
        assert raised.any() and (~raised).any()  # a straightened leg lifts its robot, a bent one does not
        np.testing.assert_allclose(lowest[raised].numpy(), CLEARANCE, atol=1e-5)  # lifted just enough
    finally:
        env.close()


def test_feet_start_above_rugged_ground():
    env = _env("rough", [0.8, 1.2], types=["rugged"], num_rows=2, rugged_amplitude=[0.08, 0.08], tile_size=4.0,
               border=1.0, platform=1.0)
    try:
        gap = _foot_clearance(env)
        assert gap.min() > CLEARANCE - 1e-4  # float32 terrain heights
        base = env.scene.sim.state.base_pos_w
        over_base = base[:, 2] - env.scene.terrain.height_at(base[:, 0].float(), base[:, 1].float()).double()
        raised = over_base > C.STANDING_BASE_HEIGHT + CLEARANCE + 1e-5  # else: the height above the ground under it
        np.testing.assert_allclose(over_base[~raised].numpy(), C.STANDING_BASE_HEIGHT + CLEARANCE, atol=1e-5)
        assert raised.any()  # +-8 cm bumps under the feet
        np.testing.assert_allclose(gap.min(dim=1).values[raised].numpy(), CLEARANCE, atol=1e-4)  # just enough
    finally:
        env.close()
