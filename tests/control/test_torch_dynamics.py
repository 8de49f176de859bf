"""TorchLegDynamics (torch kinematics + MuJoCo's qM, qfrc_bias) against LegDynamics (Pinocchio).

Tolerances, on random states (any base pose, base velocities of a few units, joints within limits):

* float64: max |new - Pinocchio| <= 1e-12 x max(1, max |Pinocchio|) per quantity (observed <= ~3e-15
  relative: round-off);
* float32 (kinematics computed in float32, qM and qfrc_bias cast to float32): <= 1e-5 x the same scale
  (observed <= ~4e-7 relative);
* low-level controller torques on a simulated trajectory: <= 1e-9 N m (observed ~4e-13 N m).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import torch

from dls_quadruped.control.conventions import (
    mujoco_to_pinocchio,
    zero_qacc_acceleration,
)
from dls_quadruped.control.dynamics import LegDynamics
from dls_quadruped.control.lowlevel import LegTerms, LowLevelController
from dls_quadruped.control.torch_dynamics import (
    TorchLegDynamics,
    leg_chain_params,
    leg_mass_blocks,
    qM_addresses_from_pairs,
)
from dls_quadruped.robots.aliengo import constants as C

NAMES = ("M_leg", "h_leg", "J_leg", "Jdot_qdot", "foot_pos_w", "foot_vel_w")
B = 16


def mass_and_bias(m: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray) -> dict[str, np.ndarray]:
    """C MuJoCo's sparse inertia (data.M), its dense form and qfrc_bias per robot (position + velocity stages)."""
    d = mujoco.MjData(m)
    n = qpos.shape[0]
    out = {"sparse": np.zeros((n, m.nM)), "dense": np.zeros((n, m.nv, m.nv)), "bias": np.zeros((n, m.nv))}
    for b in range(n):
        d.qpos[:], d.qvel[:] = qpos[b], qvel[b]
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        out["sparse"][b] = d.M
        mujoco.mj_fullM(m, d, out["dense"][b])
        out["bias"][b] = d.qfrc_bias
    return out


@pytest.fixture(scope="module")
def mj_model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.MJCF_PATH))


@pytest.fixture(scope="module")
def tdyn(mj_model) -> TorchLegDynamics:
    return TorchLegDynamics(mj_model)


@pytest.fixture(scope="module")
def case(mj_model, random_states):
    """B random states with LegDynamics' terms (copied) and MuJoCo's qM, qfrc_bias."""
    qpos, qvel = random_states(B, seed=11)
    ref = {k: v.copy() for k, v in vars(LegDynamics().compute(qpos, qvel)).items()}
    return qpos, qvel, ref, mass_and_bias(mj_model, qpos, qvel)


def _terms(tdyn, case, dtype, device="cpu", qM="sparse") -> LegTerms:
    qpos, qvel, _, mb = case
    t = lambda a: torch.tensor(a, dtype=dtype, device=device)
    return tdyn.terms(t(qpos), t(qvel), t(mb[qM]), t(mb["bias"]))


def _max_rel_error(got: torch.Tensor, ref: np.ndarray) -> float:
    return float(np.max(np.abs(got.detach().cpu().double().numpy() - ref)) / max(1.0, np.max(np.abs(ref))))


@pytest.mark.parametrize("qM", ["sparse", "dense"])
def test_float64_matches_pinocchio_to_round_off(tdyn, case, qM):
    terms = _terms(tdyn, case, torch.float64, qM=qM)
    for name in NAMES:
        got = getattr(terms, name)
        assert got.dtype == torch.float64 and got.shape == case[2][name].shape, name
        err = _max_rel_error(got, case[2][name])
        assert err <= 1e-12, f"{name}: relative error {err:.2e}"


def test_float32_matches_pinocchio_to_float32_tolerance(tdyn, case):
    terms = _terms(tdyn, case, torch.float32)
    for name in NAMES:
        got = getattr(terms, name)
        assert got.dtype == torch.float32, name
        err = _max_rel_error(got, case[2][name])
        assert err <= 1e-5, f"{name}: relative error {err:.2e}"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_on_cuda_matches_pinocchio(tdyn, case, dtype, tol):
    terms = _terms(tdyn, case, dtype, device="cuda")
    for name in NAMES:
        got = getattr(terms, name)
        assert got.device.type == "cuda", name
        assert _max_rel_error(got, case[2][name]) <= tol, name


def test_sparse_layouts_and_shapes_agree(tdyn, case, mj_model):
    """(B, nM), (B, 1, nM) and dense (B, nv, nv) give the same blocks; so does a sparse qM in another
    element order read through its (row, col) pairs: here MuJoCo Warp's sparse order (row i from dof_Madr[i]:
    the diagonal, then the ancestors; its model's qM_fullm_i / qM_fullm_j list the same pairs)."""
    _, _, _, mb = case
    p = tdyn.params
    ref = leg_mass_blocks(torch.tensor(mb["dense"]), p)
    assert torch.equal(leg_mass_blocks(torch.tensor(mb["sparse"]), p), ref)
    assert torch.equal(leg_mass_blocks(torch.tensor(mb["sparse"])[:, None], p), ref)
    # rebuild the sparse vector in the "diagonal, then ancestors" order from the dense matrices
    rows, cols = [], []
    for i in range(mj_model.nv):
        j = i
        while j >= 0:
            rows.append(i)
            cols.append(j)
            j = mj_model.dof_parentid[j]
    other = torch.tensor(mb["dense"][:, rows, cols])
    assert torch.equal(leg_mass_blocks(other, p, qM_addresses_from_pairs(np.array(rows), np.array(cols), p.dof_adr)),
                       ref)
    assert not np.array_equal(qM_addresses_from_pairs(np.array(rows), np.array(cols), p.dof_adr), p.qM_adr)
    with pytest.raises(ValueError, match="qM must be"):
        leg_mass_blocks(torch.zeros(2, 3, 4, 5), p)


def test_qfrc_bias_convention(mj_model, case):
    """MuJoCo's qfrc_bias is Pinocchio's rnea at a0 = [-omega_b x v_b, 0, 0] (MuJoCo's qacc = 0) in MuJoCo's
    coordinates: leg rows equal, base rows [R f_b; tau_b]. Pinocchio's nle (v_dot = 0) differs on the leg rows by
    M_pin[leg, 0:3] (omega_b x v_b)."""
    qpos, qvel, _, mb = case
    model = pin.buildModelFromMJCF(str(C.MJCF_PATH))
    data = model.createData()
    q, v = mujoco_to_pinocchio(qpos, qvel)
    a0 = zero_qacc_acceleration(v)
    worst_nle_gap = 0.0
    for b in range(qpos.shape[0]):
        h = pin.rnea(model, data, q[b], v[b], a0[b]).copy()
        R = pin.Quaternion(q[b, 6], *q[b, 3:6]).toRotationMatrix()
        expect = np.concatenate([R @ h[0:3], h[3:]])
        np.testing.assert_allclose(mb["bias"][b], expect, rtol=0, atol=1e-11)
        nle = pin.nonLinearEffects(model, data, q[b], v[b]).copy()
        M = pin.crba(model, data, q[b]).copy()
        M = np.triu(M) + np.triu(M, 1).T
        np.testing.assert_allclose(nle[6:] - h[6:], M[6:, 0:3] @ np.cross(v[b, 3:6], v[b, 0:3]), atol=1e-11)
        worst_nle_gap = max(worst_nle_gap, np.abs(nle[6:] - h[6:]).max())
    assert worst_nle_gap > 1e-2  # the two conventions really differ on these states


def test_full_foot_jacobian_matches_mujoco(tdyn, case, mj_model):
    """[J_base, J_leg] are MuJoCo's mj_jacSite columns (base: qvel[0:6] = v_w, omega_b), and the foot
    velocity is J_full qvel."""
    qpos, qvel, _, _ = case
    kin = tdyn.kinematics(torch.tensor(qpos), torch.tensor(qvel))
    d = mujoco.MjData(mj_model)
    jacp = np.zeros((3, mj_model.nv))
    for b in range(qpos.shape[0]):
        d.qpos[:], d.qvel[:] = qpos[b], qvel[b]
        mujoco.mj_kinematics(mj_model, d)
        mujoco.mj_comPos(mj_model, d)
        for leg, name in enumerate(C.FOOT_NAMES):
            mujoco.mj_jacSite(mj_model, d, jacp, None, mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_SITE, name))
            np.testing.assert_allclose(kin.J_base[b, leg].numpy(), jacp[:, 0:6], rtol=0, atol=1e-13)
            np.testing.assert_allclose(kin.J_leg[b, leg].numpy(), jacp[:, 6 + 3 * leg : 9 + 3 * leg], rtol=0,
                                       atol=1e-13)
    qd = torch.tensor(qvel[:, 6:]).view(-1, 4, 3, 1)
    v = (kin.J_base @ torch.tensor(qvel[:, None, 0:6, None])).squeeze(-1) + (kin.J_leg @ qd).squeeze(-1)
    torch.testing.assert_close(v, kin.foot_vel_w, rtol=0, atol=1e-13)


def test_generic_chain_parameters_match_mujoco(random_states):
    """Rotated bodies, off-origin joint anchors, tilted axes and nonzero joint references (none of which the
    AlienGo has) against MuJoCo's own site position, mj_jacSite and mj_jacDot on the modified model."""
    spec = mujoco.MjSpec.from_file(str(C.MJCF_PATH))
    rng = np.random.default_rng(3)
    for leg in C.LEG_NAMES:
        for part in ("hip", "thigh", "calf"):
            quat = rng.standard_normal(4)
            spec.body(f"{leg}_{part}").quat = quat / np.linalg.norm(quat)
            joint = spec.joint(f"{leg}_{part}_joint")
            joint.pos = rng.uniform(-0.03, 0.03, 3)
            joint.axis = rng.standard_normal(3)
            joint.ref = rng.uniform(-0.5, 0.5)
    m = spec.compile()
    p = leg_chain_params(m)
    assert np.all(p.qpos0 != 0.0) and np.all(p.anchor != 0.0)
    qpos, qvel = random_states(6, seed=4)
    kin = TorchLegDynamics(m).kinematics(torch.tensor(qpos), torch.tensor(qvel))
    d = mujoco.MjData(m)
    jacp, jacdot = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for b in range(qpos.shape[0]):
        d.qpos[:], d.qvel[:] = qpos[b], qvel[b]
        mujoco.mj_forward(m, d)
        for leg, name in enumerate(C.FOOT_NAMES):
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
            mujoco.mj_jacSite(m, d, jacp, None, sid)
            mujoco.mj_jacDot(m, d, jacdot, None, d.site_xpos[sid], m.site_bodyid[sid])
            np.testing.assert_allclose(kin.foot_pos_w[b, leg].numpy(), d.site_xpos[sid], rtol=0, atol=1e-13)
            np.testing.assert_allclose(kin.foot_vel_w[b, leg].numpy(), jacp @ d.qvel, rtol=0, atol=1e-12)
            np.testing.assert_allclose(kin.J_leg[b, leg].numpy(), jacp[:, 6 + 3 * leg : 9 + 3 * leg], rtol=0,
                                       atol=1e-13)
            np.testing.assert_allclose(kin.Jdot_qdot[b, leg].numpy(), jacdot @ d.qvel, rtol=0, atol=1e-11)


def test_rows_are_independent_and_quaternion_is_normalised(tdyn, random_states):
    qpos, qvel = random_states(4, seed=8)
    clean = tdyn.kinematics(torch.tensor(qpos), torch.tensor(qvel))
    bad_pos, bad_vel = qpos.copy(), qvel.copy()
    bad_pos[:, 3:7] *= 1.7  # any norm
    bad_pos[1, 3:7] = np.nan
    bad_vel[2, 0] = np.inf
    got = tdyn.kinematics(torch.tensor(bad_pos), torch.tensor(bad_vel))
    for name in ("foot_pos_w", "foot_vel_w", "J_leg", "J_base", "Jdot_qdot"):
        torch.testing.assert_close(getattr(got, name)[[0, 3]], getattr(clean, name)[[0, 3]], rtol=0, atol=1e-14)
    assert not torch.isfinite(got.foot_pos_w[1]).all() and not torch.isfinite(got.foot_vel_w[2]).all()


def test_bad_inputs_and_layouts_are_rejected(tdyn, tmp_path):
    with pytest.raises(ValueError, match=r"qpos \(B, 19\)"):
        tdyn.kinematics(torch.zeros(2, 18, dtype=torch.float64), torch.zeros(2, 18, dtype=torch.float64))
    with pytest.raises(ValueError, match="batch sizes differ"):
        tdyn.kinematics(torch.zeros(2, 19, dtype=torch.float64), torch.zeros(3, 18, dtype=torch.float64))
    with pytest.raises(ValueError, match="one dtype"):
        tdyn.kinematics(torch.zeros(2, 19, dtype=torch.float64), torch.zeros(2, 18, dtype=torch.float32))
    with pytest.raises(ValueError, match="qfrc_bias must be"):
        tdyn.terms(torch.zeros(2, 19, dtype=torch.float64), torch.zeros(2, 18, dtype=torch.float64),
                   torch.zeros(2, 18, 18, dtype=torch.float64), torch.zeros(2, 17, dtype=torch.float64))
    text = C.MJCF_PATH.read_text().replace('"FL_hip_joint"', '"FL_abad_joint"')
    path = tmp_path / "renamed.xml"
    path.write_text(text)
    with pytest.raises(ValueError, match="'FL_hip_joint' missing"):
        TorchLegDynamics(mujoco.MjModel.from_xml_path(str(path)))


def test_controller_torques_agree_on_a_simulated_trajectory():
    """Two LowLevelControllers driven with the same references along one MuJoCo trajectory (the scene with the
    ground, 4 robots trotting in place from perturbed starts, 0.8 s): one fed Pinocchio's LegTerms (its torques
    drive the simulation, as sim/shard.py does), one fed TorchLegTerms from the same state's qM and qfrc_bias.
    Both make the same contact decisions and torques to round-off, through swings and stances."""
    m = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    n, steps = 4, 160
    rng = np.random.default_rng(5)
    datas = []
    for _ in range(n):
        d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, d, 0)
        d.qpos[7:] += rng.uniform(-0.1, 0.1, 12)
        d.qvel[:] = rng.uniform(-0.3, 0.3, m.nv)
        datas.append(d)
    pin_dyn, tdyn = LegDynamics(), TorchLegDynamics(m)
    ctrl_pin = LowLevelController(n, dt=m.opt.timestep)
    ctrl_new = LowLevelController(n, dt=m.opt.timestep)

    def terms() -> tuple[LegTerms, LegTerms]:
        for d in datas:
            mujoco.mj_forward(m, d)  # qM, qfrc_bias of this state (after mj_step they are the previous one's)
        qpos = np.stack([d.qpos for d in datas])
        qvel = np.stack([d.qvel for d in datas])
        r = pin_dyn.compute(qpos, qvel)
        ref = LegTerms(*(torch.from_numpy(getattr(r, k).copy()) for k in NAMES))
        new = tdyn.terms(torch.from_numpy(qpos), torch.from_numpy(qvel),
                         torch.from_numpy(np.stack([d.M for d in datas])),
                         torch.from_numpy(np.stack([d.qfrc_bias for d in datas])))
        return ref, new

    ref, new = terms()
    ctrl_pin.reset(torch.arange(n), ref.foot_pos_w)
    ctrl_new.reset(torch.arange(n), new.foot_pos_w)
    freq = torch.full((n, 4), 2.5, dtype=torch.float64)
    duty = torch.full((n, 4), 0.6, dtype=torch.float64)
    p_td = ref.foot_pos_w.clone()
    p_td[..., 2] = C.FOOT_RADIUS
    F = torch.zeros(n, 4, 3, dtype=torch.float64)
    F[..., 2] = C.WEIGHT / 2.0
    limit = torch.as_tensor(C.TORQUE_LIMITS).view(4, 3)
    worst, free_swing_torques = 0.0, 0
    for _ in range(steps):
        ref, new = terms()
        tau_pin = ctrl_pin.compute(ref, freq, duty, p_td, F)
        tau_new = ctrl_new.compute(new, freq, duty, p_td, F)
        assert torch.equal(ctrl_pin.contact, ctrl_new.contact)
        worst = max(worst, float((tau_pin - tau_new).abs().max()))
        swing = ~ctrl_pin.contact.unsqueeze(-1)
        free_swing_torques += int((swing & (tau_pin.view(n, 4, 3).abs() < limit)).sum())
        for d, tau in zip(datas, tau_pin.numpy()):
            d.ctrl[:] = tau
            mujoco.mj_step(m, d)
    assert worst <= 1e-9, f"max torque difference {worst:.3e} N m"
    assert free_swing_torques > steps  # the swing law (M, h, J, Jdot qdot all used) acted below the clip
    assert all(np.isfinite(d.qpos).all() for d in datas)
