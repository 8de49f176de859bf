"""SRBD model: against an independent per-sample numpy integrator, hand-worked cases, invariants."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.core.rotations import euler_from_quat
from dls_quadruped.mpc.srbd import (
    SRBDModel,
    euler_rate_matrix_inv,
    robot_srbd_model,
    rollout_reference,
    rotation_from_euler,
    srbd_state_from_base,
)
from dls_quadruped.robots.aliengo import constants as C

DT = 0.02


def _rx(a):
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def _ry(a):
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _rz(a):
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def numpy_rollout(x0, contact, target, force, mass, inertia, g, dt):
    """Independent explicit-Euler SRBD, one sample at a time, float64.

    E' is built from its definition (omega_b = e_x roll' + Rx^T e_y pitch' + Rx^T Ry^T e_z yaw')
    and inverted numerically rather than taken from eq. C.2.3.
    """
    x = np.array(x0, dtype=np.float64)
    out = [x.copy()]
    for k in range(contact.shape[0]):
        p, v, phi, w = x[0:3], x[3:6], x[6:9], x[9:12]
        feet = x[12:24].reshape(4, 3)
        rot = _rz(phi[2]) @ _ry(phi[1]) @ _rx(phi[0])
        f_sum = np.zeros(3)
        tau_w = np.zeros(3)
        for i in range(4):
            if contact[k, i]:
                f_sum += force[k, i]
                tau_w += np.cross(feet[i] - p, force[k, i])
        e_prime = np.stack([np.array([1.0, 0, 0]), _rx(phi[0]).T @ np.array([0, 1.0, 0]),
                            _rx(phi[0]).T @ _ry(phi[1]).T @ np.array([0, 0, 1.0])], axis=1)
        phi_dot = np.linalg.solve(e_prime, w)
        w_dot = np.linalg.solve(inertia, rot.T @ tau_w - np.cross(w, inertia @ w))
        new_feet = np.array([feet[i] if contact[k, i] else target[k, i] for i in range(4)])
        x = np.concatenate([p + dt * v, v + dt * (np.array([0, 0, -g]) + f_sum / mass), phi + dt * phi_dot,
                            w + dt * w_dot, new_feet.ravel()])
        out.append(x.copy())
    return np.stack(out)


def _random_inputs(gen, b=2, m=3, n=6):
    x0 = torch.zeros(b, 24)
    x0[:, 0:3] = torch.tensor([0.1, -0.2, 0.33]) + 0.05 * torch.randn(b, 3, generator=gen)
    x0[:, 3:6] = 0.5 * torch.randn(b, 3, generator=gen)
    x0[:, 6:9] = 0.2 * torch.randn(b, 3, generator=gen)
    x0[:, 9:12] = torch.randn(b, 3, generator=gen)
    x0[:, 12:24] = (torch.tensor(C.HIP_OFFSETS_B, dtype=torch.float32) * torch.tensor([1.0, 2.5, 0])
                    + 0.03 * torch.randn(4, 3, generator=gen)).flatten()
    contact = torch.rand(b, m, n, 4, generator=gen) < 0.6
    target = 0.3 * torch.randn(b, m, n, 4, 3, generator=gen)
    force = torch.randn(b, m, n, 4, 3, generator=gen) * torch.tensor([20.0, 20.0, 40.0]) + torch.tensor([0, 0, 60.0])
    return x0, contact, target, force


def test_rollout_matches_independent_numpy_integrator():
    gen = torch.Generator().manual_seed(3)
    model = robot_srbd_model()
    x0, contact, target, force = _random_inputs(gen)
    traj = rollout_reference(x0, contact, target, force, model, DT)
    inertia = np.array(model.inertia_b)
    for b in range(x0.shape[0]):
        for m in range(contact.shape[1]):
            expected = numpy_rollout(x0[b].numpy(), contact[b, m].numpy(), target[b, m].numpy(),
                                     force[b, m].numpy(), model.mass, inertia, model.gravity, DT)
            np.testing.assert_allclose(traj[b, m].numpy(), expected, rtol=1e-4, atol=2e-5)


def test_free_fall_by_hand():
    """No contact: p_k = p_0 + k dt v_0 - g dt^2 k (k - 1) / 2 (explicit Euler), v_k = v_0 - k g dt."""
    model = robot_srbd_model()
    n = 10
    x0 = torch.zeros(1, 24)
    x0[0, 0:3] = torch.tensor([0.0, 0.0, 1.0])
    x0[0, 3:6] = torch.tensor([0.3, 0.0, 0.5])
    contact = torch.zeros(1, 1, n, 4, dtype=torch.bool)
    target = torch.full((1, 1, n, 4, 3), 7.0)
    force = torch.full((1, 1, n, 4, 3), 100.0)  # ignored in swing
    traj = rollout_reference(x0, contact, target, force, model, DT)[0, 0]
    k = torch.arange(n + 1, dtype=torch.float32)
    g = C.GRAVITY
    torch.testing.assert_close(traj[:, 2], 1.0 + 0.5 * k * DT - g * DT**2 * k * (k - 1) / 2, rtol=0, atol=1e-5)
    torch.testing.assert_close(traj[:, 5], 0.5 - k * g * DT, rtol=0, atol=1e-5)
    torch.testing.assert_close(traj[:, 0], 0.3 * k * DT, rtol=0, atol=1e-6)
    assert torch.all(traj[1:, 12:] == 7.0)  # swing feet jumped to their target (eq. C.1.4)
    assert torch.all(traj[:, 6:12] == 0.0)  # no torque, no rotation


def test_static_support_stays_put():
    """Four stance legs, F_z = m g / 4 each, feet symmetric about the CoM: nothing moves."""
    model = robot_srbd_model()
    feet = torch.tensor([[0.24, 0.13, 0.0], [0.24, -0.13, 0.0], [-0.24, 0.13, 0.0], [-0.24, -0.13, 0.0]])
    x0 = torch.zeros(1, 24)
    x0[0, 2] = 0.33
    x0[0, 12:] = feet.flatten()
    n = 20
    contact = torch.ones(1, 1, n, 4, dtype=torch.bool)
    force = torch.zeros(1, 1, n, 4, 3)
    force[..., 2] = model.mass * model.gravity / 4
    traj = rollout_reference(x0, contact, torch.zeros(1, 1, n, 4, 3), force, model, DT)[0, 0]
    torch.testing.assert_close(traj, x0.expand(n + 1, 24), rtol=0, atol=1e-5)


def test_static_support_moment_sign():
    """Only the front legs push up: the nose goes up, i.e. the pitch rate becomes negative (y-axis rotation)."""
    model = robot_srbd_model()
    x0 = torch.zeros(1, 24)
    x0[0, 2] = 0.33
    x0[0, 12:] = torch.tensor([[0.24, 0.13, 0.0], [0.24, -0.13, 0.0], [-0.24, 0.13, 0.0],
                               [-0.24, -0.13, 0.0]]).flatten()
    contact = torch.tensor([True, True, False, False]).view(1, 1, 1, 4)
    force = torch.zeros(1, 1, 1, 4, 3)
    force[..., 2] = 50.0
    x1 = rollout_reference(x0, contact, x0[0, 12:].view(1, 1, 1, 4, 3), force, model, DT)[0, 0, 1]
    # torque_y = (r x F)_y = r_z F_x - r_x F_z = -0.24 * 100 per leg pair (r from CoM to the feet)
    inertia = torch.tensor(model.inertia_b)
    expected = DT * torch.linalg.solve(inertia, torch.tensor([0.0, -2 * 0.24 * 50.0, 0.0]))
    torch.testing.assert_close(x1[9:12], expected, rtol=1e-4, atol=1e-6)
    assert x1[10] < 0


def test_zero_force_momentum():
    """Zero force: m v changes by m g dt per step exactly; world angular momentum R I omega is
    conserved to integration accuracy (first order: halving dt roughly halves the drift)."""
    model = robot_srbd_model()
    inertia = torch.tensor(model.inertia_b, dtype=torch.float64)

    def drift(dt: float, duration: float = 0.5) -> tuple[float, torch.Tensor]:
        n = round(duration / dt)
        x0 = torch.zeros(1, 24, dtype=torch.float64)
        x0[0, 3:6] = torch.tensor([0.2, -0.1, 0.4])
        x0[0, 6:9] = torch.tensor([0.1, -0.2, 0.3])
        x0[0, 9:12] = torch.tensor([0.8, 0.3, -0.5])
        contact = torch.zeros(1, 1, n, 4, dtype=torch.bool)
        zeros = torch.zeros(1, 1, n, 4, 3, dtype=torch.float64)
        model64 = SRBDModel(model.mass, model.inertia_b, model.com_offset_b, model.gravity)
        traj = rollout_reference(x0, contact, zeros, zeros, model64, dt)[0, 0]
        rot = rotation_from_euler(traj[:, 6:9])
        ang_mom_w = (rot @ (traj[:, 9:12] @ inertia.T).unsqueeze(-1)).squeeze(-1)
        return float((ang_mom_w[-1] - ang_mom_w[0]).norm() / ang_mom_w[0].norm()), traj

    err_coarse, traj = drift(0.002)
    err_fine, _ = drift(0.001)
    assert err_coarse < 0.02
    assert err_fine < 0.6 * err_coarse  # converges with dt (explicit Euler is first order)
    lin_mom = model.mass * traj[:, 3:6]
    dp = lin_mom[1:] - lin_mom[:-1]
    torch.testing.assert_close(dp, torch.tensor([0.0, 0.0, -model.mass * model.gravity * 0.002],
                                                dtype=torch.float64).expand_as(dp), rtol=0, atol=1e-9)


def test_euler_maps_independent():
    gen = torch.Generator().manual_seed(0)
    euler = (torch.rand(20, 3, generator=gen) - 0.5) * torch.tensor([2.0, 2.0, 6.0])
    rot = rotation_from_euler(euler.double())
    for e, r in zip(euler.double().numpy(), rot.numpy()):
        np.testing.assert_allclose(r, _rz(e[2]) @ _ry(e[1]) @ _rx(e[0]), atol=1e-12)
        e_prime = np.stack([[1.0, 0, 0], _rx(e[0]).T @ [0, 1.0, 0], _rx(e[0]).T @ _ry(e[1]).T @ [0, 0, 1.0]], axis=1)
        np.testing.assert_allclose(euler_rate_matrix_inv(torch.tensor(e)).numpy(), np.linalg.inv(e_prime), atol=1e-10)
    # quaternion of R = Rz Ry Rx is q_z * q_y * q_x; euler_from_quat must invert it
    half = euler.double() / 2
    qx = torch.stack([half[:, 0].cos(), half[:, 0].sin(), 0 * half[:, 0], 0 * half[:, 0]], -1)
    qy = torch.stack([half[:, 1].cos(), 0 * half[:, 1], half[:, 1].sin(), 0 * half[:, 1]], -1)
    qz = torch.stack([half[:, 2].cos(), 0 * half[:, 2], 0 * half[:, 2], half[:, 2].sin()], -1)

    def qmul(a, b):
        aw, ax, ay, az = a.unbind(-1)
        bw, bx, by, bz = b.unbind(-1)
        return torch.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)

    torch.testing.assert_close(euler_from_quat(qmul(qmul(qz, qy), qx)), euler.double(), rtol=0, atol=1e-9)


def test_model_from_mjcf():
    model = robot_srbd_model()
    inertia = np.array(model.inertia_b)
    np.testing.assert_allclose(inertia, inertia.T, atol=1e-12)
    eig = np.linalg.eigvalsh(inertia)
    assert np.all(eig > 0) and eig[0] + eig[1] >= eig[2]  # a physical inertia (triangle inequality)
    assert model.mass == pytest.approx(C.TOTAL_MASS)
    # the legs hang below the trunk and the 4 x (hip + thigh + calf) adds to roll inertia: more than the trunk alone
    assert inertia[0, 0] > 0.0333 and inertia[1, 1] > 0.161 and inertia[2, 2] > 0.1746
    assert np.linalg.norm(model.com_offset_b) < 0.05
    assert model.com_offset_b[2] < 0  # legs below the base origin pull the CoM down


def test_state_from_base_com_offset():
    model = robot_srbd_model()
    quat = torch.tensor([[np.cos(0.4), 0.0, 0.0, np.sin(0.4)]], dtype=torch.float32)  # yaw 0.8 rad
    pos = torch.tensor([[1.0, 2.0, 0.35]])
    ang_vel_b = torch.tensor([[0.0, 0.0, 1.0]])
    st = srbd_state_from_base(pos, quat, torch.zeros(1, 3), ang_vel_b, torch.zeros(1, 4, 3), model)
    c = torch.tensor(model.com_offset_b)
    expected = pos[0] + torch.tensor([[np.cos(0.8), -np.sin(0.8), 0], [np.sin(0.8), np.cos(0.8), 0], [0, 0, 1]],
                                     dtype=torch.float32) @ c
    torch.testing.assert_close(st.com_pos_w[0], expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(st.euler[0], torch.tensor([0.0, 0.0, 0.8]), rtol=0, atol=1e-6)
    # v_c = R (omega x c): yaw rotation of an offset point
    v_b = torch.cross(ang_vel_b[0], c, dim=0)
    assert torch.allclose(st.com_vel_w[0].norm(), v_b.norm(), atol=1e-7)
