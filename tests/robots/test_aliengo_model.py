"""The AlienGo MJCF agrees with constants.py, loads in MuJoCo and Pinocchio, and both see the same robot."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from dls_quadruped.control.conventions import mujoco_to_pinocchio
from dls_quadruped.robots.aliengo import constants as C


@pytest.fixture(scope="module")
def mj() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.MJCF_PATH))


@pytest.fixture(scope="module")
def pin_model() -> pin.Model:
    return pin.buildModelFromMJCF(str(C.MJCF_PATH))


def body_id(m: mujoco.MjModel, name: str) -> int:
    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)


def test_scene_loads_with_floor():
    m = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor") >= 0
    assert m.nq == 19 and m.nv == 18 and m.nu == 12


def test_total_and_link_masses(mj, pin_model):
    assert mj.body_mass.sum() == pytest.approx(C.TOTAL_MASS, abs=1e-9)
    assert sum(inertia.mass for inertia in pin_model.inertias) == pytest.approx(C.TOTAL_MASS, abs=1e-9)
    assert C.TOTAL_MASS == pytest.approx(24.638, abs=1e-3)  # SPEC section 3: ~24.64 kg
    assert mj.body_mass[body_id(mj, C.BASE_BODY_NAME)] == pytest.approx(C.BASE_MASS)
    for leg in C.LEG_NAMES:
        for link, mass in (("hip", C.HIP_MASS), ("thigh", C.THIGH_MASS), ("calf", C.CALF_MASS)):
            assert mj.body_mass[body_id(mj, f"{leg}_{link}")] == pytest.approx(mass), f"{leg}_{link}"


def test_joint_names_order_and_addresses(mj, pin_model):
    names = tuple(mj.joint(i).name for i in range(1, mj.njnt))
    assert names == C.JOINT_NAMES
    assert mj.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    np.testing.assert_array_equal(mj.jnt_qposadr[1:], np.arange(7, 19))
    np.testing.assert_array_equal(mj.jnt_dofadr[1:], np.arange(6, 18))
    assert tuple(pin_model.names)[2:] == C.JOINT_NAMES


def test_joint_axes(mj):
    axes = {"hip": [1.0, 0.0, 0.0], "thigh": [0.0, 1.0, 0.0], "calf": [0.0, 1.0, 0.0]}
    for name in C.JOINT_NAMES:
        np.testing.assert_array_equal(mj.joint(name).axis, axes[name.split("_")[1]], err_msg=name)


def test_joint_ranges_and_torque_limits(mj, pin_model):
    np.testing.assert_allclose(mj.jnt_range[1:], C.JOINT_RANGES)
    assert np.all(mj.jnt_limited[1:])
    np.testing.assert_allclose(pin_model.lowerPositionLimit[7:], C.JOINT_RANGES[:, 0])
    np.testing.assert_allclose(pin_model.upperPositionLimit[7:], C.JOINT_RANGES[:, 1])
    # actuator i drives joint i (leg-major) with ctrl range +- the torque limit
    driven = [mj.joint(int(j)).name for j in mj.actuator_trnid[:, 0]]
    assert tuple(driven) == C.JOINT_NAMES
    np.testing.assert_allclose(mj.actuator_ctrlrange, np.stack([-C.TORQUE_LIMITS, C.TORQUE_LIMITS], axis=1))
    assert np.all(mj.actuator_ctrllimited)
    np.testing.assert_allclose(mj.actuator_gear[:, 0], 1.0)  # ctrl is the joint torque


def test_leg_geometry(mj):
    for leg_index, leg in enumerate(C.LEG_NAMES):
        np.testing.assert_allclose(mj.body_pos[body_id(mj, f"{leg}_hip")], C.HIP_OFFSETS_B[leg_index])
        thigh = [0.0, C.LEG_Y_SIGN[leg_index] * C.THIGH_OFFSET_Y, 0.0]
        np.testing.assert_allclose(mj.body_pos[body_id(mj, f"{leg}_thigh")], thigh)
        np.testing.assert_allclose(mj.body_pos[body_id(mj, f"{leg}_calf")], [0.0, 0.0, -C.THIGH_LENGTH])
        site = mj.site(C.FOOT_NAMES[leg_index])
        assert mj.body(int(site.bodyid[0])).name == f"{leg}_calf"
        np.testing.assert_allclose(site.pos, [0.0, 0.0, -C.CALF_LENGTH])
        geom = mj.geom(C.FOOT_GEOM_NAMES[leg_index])
        assert geom.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
        assert geom.size[0] == pytest.approx(C.FOOT_RADIUS)
        np.testing.assert_allclose(geom.pos, site.pos)  # the site marks the sphere centre


def test_home_keyframe_stands_on_the_ground():
    m = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    assert d.qpos[2] == pytest.approx(C.STANDING_BASE_HEIGHT + 0.005, abs=1e-4)
    np.testing.assert_allclose(d.qpos[7:], C.NOMINAL_JOINT_POS)
    mujoco.mj_forward(m, d)
    feet = np.stack([d.site(name).xpos for name in C.FOOT_NAMES])
    # sphere bottoms 5 mm above the floor (keyframe margin), none touching
    np.testing.assert_allclose(feet[:, 2] - C.FOOT_RADIUS, 0.005, atol=2e-3)
    assert d.ncon == 0
    # feet under the hips: hip joint x (world, base at the origin, level) vs foot x
    np.testing.assert_allclose(feet[:, 0], C.HIP_OFFSETS_B[:, 0], atol=0.01)
    np.testing.assert_allclose(np.abs(feet[:, 1]), C.HIP_OFFSET_Y + C.THIGH_OFFSET_Y, atol=1e-9)
    # base height and nominal hip height agree to a couple of cm
    assert abs(C.STANDING_BASE_HEIGHT - C.HIP_HEIGHT) < 0.02


def test_pinocchio_feet_equal_mujoco_sites(mj, pin_model):
    rng = np.random.default_rng(7)
    d = mujoco.MjData(mj)
    pdata = pin_model.createData()
    frame_ids = [pin_model.getFrameId(name) for name in C.FOOT_NAMES]
    for _ in range(20):
        quat = rng.standard_normal(4)
        qpos = np.r_[rng.uniform(-1.0, 1.0, 3), quat / np.linalg.norm(quat), rng.uniform(*C.JOINT_RANGES.T)]
        d.qpos[:] = qpos
        mujoco.mj_kinematics(mj, d)
        q, _ = mujoco_to_pinocchio(qpos[None], np.zeros((1, 18)))
        pin.framesForwardKinematics(pin_model, pdata, q[0])
        for name, fid in zip(C.FOOT_NAMES, frame_ids):
            np.testing.assert_allclose(pdata.oMf[fid].translation, d.site(name).xpos, atol=1e-12, err_msg=name)
