"""LegDynamics (Pinocchio) cross-checked against MuJoCo's own quantities on random states.

Every output is compared with MuJoCo on the same MJCF: mj_fullM leg blocks, qfrc_bias leg
entries, mj_jacSite leg columns, mj_jacDot(site point) @ qvel, site_xpos and jacp @ qvel.
Tolerance: 1e-8 absolute on quantities of order 1-100 (both sides are exact rigid-body
algorithms in float64; the observed differences are ~1e-13).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from dls_quadruped.control.conventions import (
    mujoco_to_pinocchio,
    pinocchio_to_mujoco,
    quat_wxyz_to_matrix,
    zero_qacc_acceleration,
)
from dls_quadruped.control.dynamics import LegDynamics
from dls_quadruped.robots.aliengo import constants as C

TOL = 1e-8
NUM_STATES = 24


@pytest.fixture(scope="module")
def mj_model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.MJCF_PATH))


@pytest.fixture(scope="module")
def dyn() -> LegDynamics:
    return LegDynamics()


def mujoco_reference(m: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray) -> dict[str, np.ndarray]:
    """The same per-leg quantities computed by MuJoCo, one robot at a time."""
    d = mujoco.MjData(m)
    B = qpos.shape[0]
    ref = {k: np.zeros((B, 4, 3, 3)) for k in ("M_leg", "J_leg")}
    ref.update({k: np.zeros((B, 4, 3)) for k in ("h_leg", "Jdot_qdot", "foot_pos_w", "foot_vel_w")})
    site_ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n) for n in C.FOOT_NAMES]
    M = np.zeros((m.nv, m.nv))
    jacp, jacdot = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for b in range(B):
        d.qpos[:], d.qvel[:] = qpos[b], qvel[b]
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)  # mujoco >= 3.3 signature
        for leg, sid in enumerate(site_ids):
            cols = slice(6 + 3 * leg, 9 + 3 * leg)
            mujoco.mj_jacSite(m, d, jacp, None, sid)
            mujoco.mj_jacDot(m, d, jacdot, None, d.site_xpos[sid], m.site_bodyid[sid])
            ref["M_leg"][b, leg] = M[cols, cols]
            ref["h_leg"][b, leg] = d.qfrc_bias[cols]
            ref["J_leg"][b, leg] = jacp[:, cols]
            ref["Jdot_qdot"][b, leg] = jacdot @ d.qvel
            ref["foot_pos_w"][b, leg] = d.site_xpos[sid]
            ref["foot_vel_w"][b, leg] = jacp @ d.qvel
    return ref


def test_model_has_no_armature_damping_and_same_gravity(mj_model, dyn):
    # M and qfrc_bias only match Pinocchio's rigid-body terms without these passive extras.
    assert np.all(mj_model.dof_armature == 0.0)
    assert np.all(mj_model.dof_damping == 0.0)
    np.testing.assert_allclose(mj_model.opt.gravity, [0.0, 0.0, -C.GRAVITY])
    np.testing.assert_allclose(dyn.model.gravity.linear, [0.0, 0.0, -C.GRAVITY])


@pytest.mark.parametrize("name", ["M_leg", "h_leg", "J_leg", "Jdot_qdot", "foot_pos_w", "foot_vel_w"])
def test_matches_mujoco(mj_model, dyn, name, random_states):
    qpos, qvel = random_states(NUM_STATES, seed=1)
    ref = mujoco_reference(mj_model, qpos, qvel)
    got = getattr(dyn.compute(qpos, qvel), name)
    assert np.all(np.abs(ref[name]) < 1e3)  # the comparison below is absolute
    assert np.max(np.abs(got - ref[name])) < TOL, f"{name}: max error {np.max(np.abs(got - ref[name])):.3e}"


def test_base_motion_matters_for_h_and_jdot(mj_model, dyn, random_states):
    """The conventions are exercised: with the base velocity zeroed the answers change."""
    qpos, qvel = random_states(4, seed=2)
    full = {k: v.copy() for k, v in vars(dyn.compute(qpos, qvel)).items()}
    still = qvel.copy()
    still[:, :6] = 0.0
    legs_only = dyn.compute(qpos, still)
    assert np.max(np.abs(full["h_leg"] - legs_only.h_leg)) > 1e-2
    assert np.max(np.abs(full["Jdot_qdot"] - legs_only.Jdot_qdot)) > 1e-1


def test_unnormalised_quaternion_is_normalised(mj_model, dyn, random_states):
    qpos, qvel = random_states(3, seed=3)
    ref = {k: v.copy() for k, v in vars(dyn.compute(qpos, qvel)).items()}
    scaled = qpos.copy()
    scaled[:, 3:7] *= 1.7
    got = dyn.compute(scaled, qvel)
    for name, value in ref.items():
        np.testing.assert_allclose(getattr(got, name), value, atol=1e-12, err_msg=name)


def test_batched_equals_per_robot(dyn, random_states):
    qpos, qvel = random_states(7, seed=4)
    batched = {k: v.copy() for k, v in vars(dyn.compute(qpos, qvel)).items()}
    single = LegDynamics()  # another instance: buffers of batch size 1
    for b in range(qpos.shape[0]):
        one = single.compute(qpos[b : b + 1], qvel[b : b + 1])
        for name, value in batched.items():
            np.testing.assert_allclose(getattr(one, name)[0], value[b], rtol=0.0, atol=1e-13, err_msg=name)


def test_conversions_round_trip_and_frames(random_states):
    qpos, qvel = random_states(5, seed=5)
    q, v = mujoco_to_pinocchio(qpos, qvel)
    np.testing.assert_allclose(q[:, 3:7], qpos[:, [4, 5, 6, 3]], atol=1e-15)  # xyzw <- wxyz (unit input)
    R = quat_wxyz_to_matrix(qpos[:, 3:7])
    np.testing.assert_allclose(np.einsum("bij,bj->bi", R, v[:, :3]), qvel[:, :3], atol=1e-14)  # v_w = R v_b
    np.testing.assert_array_equal(v[:, 3:], qvel[:, 3:])  # omega_b and joint rates unchanged
    qpos2, qvel2 = pinocchio_to_mujoco(q, v)
    np.testing.assert_allclose(qpos2, qpos, atol=1e-14)
    np.testing.assert_allclose(qvel2, qvel, atol=1e-14)


def test_quaternion_matrix_by_hand():
    # 90 deg about z: (w, x, y, z) = (cos 45, 0, 0, sin 45) maps x -> y.
    s = np.sqrt(0.5)
    R = quat_wxyz_to_matrix(np.array([[s, 0.0, 0.0, s]]))[0]
    np.testing.assert_allclose(R, [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-15)


def test_zero_qacc_acceleration_by_hand():
    # Base spinning about z at 1 rad/s while moving along body x at 2 m/s: the world velocity is
    # constant only if the body-frame velocity rotates backwards, d(v_b)/dt = -omega x v_b = (0, -2, 0).
    v = np.zeros((1, 18))
    v[0, 0], v[0, 5] = 2.0, 1.0
    np.testing.assert_allclose(zero_qacc_acceleration(v)[0, :3], [0.0, -2.0, 0.0])
    assert np.all(zero_qacc_acceleration(v)[0, 3:] == 0.0)


def test_bad_shapes_are_rejected(dyn):
    with pytest.raises(ValueError, match=r"qpos \(B, 19\)"):
        dyn.compute(np.zeros((2, 18)), np.zeros((2, 18)))
    with pytest.raises(ValueError, match="batch sizes differ"):
        dyn.compute(np.zeros((2, 19)), np.zeros((3, 18)))


def test_generic_joint_axis_and_placement_paths_agree(dyn, random_states):
    """The Rodrigues / rotated-placement branches of the foot kinematics give the same feet.

    The AlienGo only exercises the principal-axis branch; forcing the generic ones (private
    switches) checks them on the same states.
    """
    qpos, qvel = random_states(6, seed=6)
    ref = dyn.compute(qpos, qvel).foot_pos_w.copy()
    generic = LegDynamics()
    generic._principal_axis = [-1, -1, -1]
    generic._place_is_identity = [False, False, False]
    np.testing.assert_allclose(generic.compute(qpos, qvel).foot_pos_w, ref, atol=1e-14)


def test_non_finite_robot_does_not_spoil_the_others(dyn, random_states):
    qpos, qvel = random_states(4, seed=8)
    clean = {k: v.copy() for k, v in vars(dyn.compute(qpos, qvel)).items()}
    qpos[1, 3:7] = np.nan
    qvel[2, 0] = np.inf
    got = dyn.compute(qpos, qvel)
    for name, value in clean.items():
        np.testing.assert_array_equal(getattr(got, name)[[0, 3]], value[[0, 3]], err_msg=name)
    assert not np.isfinite(got.foot_pos_w[1]).all()
    assert not np.isfinite(got.foot_vel_w[2]).all()


def test_wrong_joint_order_is_rejected(tmp_path):
    text = C.MJCF_PATH.read_text().replace('"FL_hip_joint"', '"FL_abad_joint"')
    path = tmp_path / "renamed.xml"
    path.write_text(text)
    with pytest.raises(ValueError, match="differs from constants.JOINT_NAMES"):
        LegDynamics(path)
