"""The low-level controller's two swing solves agree, and its state is updated in place (``control/lowlevel.py``).

``solve="cramer"`` (the Warp backends': elementwise, fusable, no LAPACK pivot read-back) against ``solve="lu"``
(``torch.linalg.solve_ex``, the CPU backend's), on damped leg systems from real leg Jacobians and on
near-singular ones; and the buffers a compiled physics step points at keep their storage through ``compute``,
``reset`` and ``load_state_dict``.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.control.lowlevel import LowLevelController, solve3_spd
from dls_quadruped.control.torch_dynamics import TorchLegDynamics
from dls_quadruped.robots.aliengo import constants as C


@pytest.fixture(scope="module")
def legs():
    """Leg terms of 6 robots at the home pose with joint offsets and random velocities (MuJoCo's qM, bias)."""
    m = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    rng = np.random.default_rng(3)
    qpos, qvel, qM, bias = [], [], [], []
    for _ in range(6):
        d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, d, 0)
        d.qpos[7:] += rng.uniform(-0.3, 0.3, 12)
        d.qvel[:] = rng.uniform(-1.0, 1.0, m.nv)
        mujoco.mj_forward(m, d)
        qpos.append(d.qpos.copy()), qvel.append(d.qvel.copy()), qM.append(d.M.copy()), bias.append(d.qfrc_bias.copy())
    t = [torch.from_numpy(np.stack(a)) for a in (qpos, qvel, qM, bias)]
    return TorchLegDynamics(m).terms(*t)


def test_cramer_matches_lu_on_leg_systems_and_near_singular_ones():
    g = torch.Generator().manual_seed(0)
    J = torch.randn(500, 3, 3, dtype=torch.float64, generator=g) * 0.3
    J[:100, :, 2] = J[:100, :, 1] * (1 + 1e-9)  # 100 legs with (almost) dependent columns: the damping carries them
    A = J.transpose(-1, -2) @ J + torch.eye(3, dtype=torch.float64) * 1e-6  # lambda = 1e-3, as LowLevelConfig
    b = torch.randn(500, 3, dtype=torch.float64, generator=g)
    lu = torch.linalg.solve(A, b)
    cr = solve3_spd(A, b)
    rel = ((cr - lu).norm(dim=-1) / lu.norm(dim=-1)).max()
    assert rel < 1e-6, rel  # cond(A) up to ~1e5 here: round-off times the condition number
    assert ((cr[100:] - lu[100:]).norm(dim=-1) / lu[100:].norm(dim=-1)).max() < 1e-11  # well-conditioned legs
    resid = (A @ cr.unsqueeze(-1)).squeeze(-1) - b  # it solves the system itself, to round-off relative to |A| |x|
    assert (resid.norm(dim=-1) / (A.flatten(1).norm(dim=-1) * cr.norm(dim=-1))).max() < 1e-12
    sing = torch.zeros(1, 3, 3, dtype=torch.float64)
    assert not torch.isfinite(solve3_spd(sing, torch.ones(1, 3, dtype=torch.float64))).all()  # as LU: non-finite


def test_controllers_with_either_solve_agree_and_keep_their_storage(legs):
    n = legs.foot_pos_w.shape[0]
    ctrls = {s: LowLevelController(n, dt=0.005, solve=s) for s in ("lu", "cramer")}
    for c in ctrls.values():
        c.reset(torch.arange(n), legs.foot_pos_w)
    ptrs = {k: getattr(ctrls["cramer"], k).data_ptr() for k in LowLevelController.STATE_FIELDS}
    freq = torch.full((n, 4), 2.5, dtype=torch.float64)
    duty = torch.full((n, 4), 0.6, dtype=torch.float64)
    p_td = legs.foot_pos_w + torch.tensor([0.05, 0.0, 0.0], dtype=torch.float64)
    F = torch.zeros(n, 4, 3, dtype=torch.float64)
    F[..., 2] = C.WEIGHT / 4.0
    swings = 0
    for _ in range(120):  # 0.6 s: every leg swings (duty 0.6 at 2.5 Hz)
        tau = {s: c.compute(legs, freq, duty, p_td, F) for s, c in ctrls.items()}
        assert torch.equal(ctrls["lu"].contact, ctrls["cramer"].contact)
        assert (tau["lu"] - tau["cramer"]).abs().max() < 1e-8
        swings += int((~ctrls["lu"].contact).sum())
    assert swings > 0
    saved = ctrls["cramer"].state_dict()
    ctrls["cramer"].reset(torch.tensor([1, 4]), legs.foot_pos_w[[1, 4]])
    ctrls["cramer"].load_state_dict(saved)
    assert {k: getattr(ctrls["cramer"], k).data_ptr() for k in LowLevelController.STATE_FIELDS} == ptrs
    assert all(torch.equal(getattr(ctrls["cramer"], k), v) for k, v in saved.items())


def test_an_unknown_solve_is_refused():
    with pytest.raises(ValueError, match=r"solve must be one of \('lu', 'cramer'\), got 'qr'"):
        LowLevelController(2, solve="qr")
