"""One height target for the RL task and the MPC (issue 12 item 9b): constants.BASE_HEIGHT_TARGET."""

from __future__ import annotations

import inspect

import mujoco
import pytest

from dls_quadruped.envs.mdp import rewards
from dls_quadruped.mpc.baseline import BaselineConfig
from dls_quadruped.mpc.srbd import com_height_reference, robot_srbd_model
from dls_quadruped.robots.aliengo import constants as C


def test_rl_target_and_mpc_reference_are_the_same_base_height():
    # RL: proprioceptive height = base z - stance foot-sphere centres (at z = foot radius on flat ground)
    rl_target = inspect.signature(rewards.base_height).parameters["target"].default
    assert rl_target + C.FOOT_RADIUS == pytest.approx(C.BASE_HEIGHT_TARGET, abs=1e-12)
    assert rl_target == pytest.approx(0.3108, abs=1e-4)  # 0.25 cos 0.9 + 0.25 cos(-0.9) = 0.3108 m
    # MPC: CoM height of that base pose, computed here from MuJoCo directly (home keyframe, base raised)
    model = mujoco.MjModel.from_xml_path(str(C.MJCF_PATH))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home"))
    data.qpos[2] = C.BASE_HEIGHT_TARGET
    data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)  # level
    mujoco.mj_forward(model, data)
    trunk = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    assert com_height_reference() == pytest.approx(data.subtree_com[trunk][2], abs=1e-9)
    assert com_height_reference() == pytest.approx(C.BASE_HEIGHT_TARGET + robot_srbd_model().com_offset_b[2])
    assert 0.320 < com_height_reference() < 0.328  # the CoM ~13.5 mm below the base; it was 0.33 by hand before
    assert BaselineConfig().com_height == com_height_reference()
