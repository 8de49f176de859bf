"""Single rigid body dynamics (thesis Appendix C): model, state, Euler maps, reference rollout.

State (24): x = [p_c (3, world), v_c (3, world), Phi = (roll, pitch, yaw) (3), omega (3, BASE frame),
p_f (4 x 3, world)]. Input per step: contact c (4, 0/1), touch-down targets p_td (4 x 3, world),
ground-reaction forces F (4 x 3, world, force of the ground on the robot).

Conventions and the typos they resolve (see docs/mpc.md):

* Euler XYZ as in Diebel (2006): the body -> world rotation is R = Rz(yaw) Ry(pitch) Rx(roll).
  Eq. C.2.1 prints Rx Ry Rz with the matrix of its *transpose* (Diebel's R maps world -> body);
  we use the body -> world matrix, whose transpose is the printed one.
* Eq. C.2.3 (inverse conjugate Euler-rate matrix) is used as printed: Phi_dot = E'^-1(Phi) omega_b.
* Angular dynamics: I omega_dot = R^T sum_i c_i (p_f,i - p_c) x F_i - omega x I omega.
  Eqs. C.1.2/C.1.3 write (p_c - p_f) x (R F): the moment arm points from the CoM to the foot
  and F is already in the world frame, so the world torque is rotated into the base frame
  with R^T (sign and frame typo).
* Integration: explicit Euler, every derivative evaluated at step k:
  p_{k+1} = p_k + dt v_k; v_{k+1} = v_k + dt (g + sum c F / m); Phi_{k+1} = Phi_k + dt E'^-1(Phi_k) omega_k;
  omega_{k+1} = omega_k + dt omega_dot_k; p_f,{k+1} = c_k p_f,k + (1 - c_k) p_td,k (eq. C.1.4).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields

import numpy as np
import torch

from dls_quadruped.core.rotations import euler_from_quat
from dls_quadruped.core.torch_cache import constant_tensor
from dls_quadruped.robots.aliengo import constants as C

STATE_DIM = 24
NUM_LEGS = C.NUM_LEGS


@dataclass(frozen=True)
class SRBDModel:
    """Constant parameters of the single rigid body.

    Attributes:
        mass: [kg] total robot mass.
        inertia_b: 3x3 [kg m^2] composite inertia about the CoM, base frame (row-major tuples).
        com_offset_b: (3,) [m] CoM position relative to the base origin, base frame.
        gravity: [m/s^2] magnitude, acting along -z world.
    """

    mass: float
    inertia_b: tuple[tuple[float, float, float], ...]
    com_offset_b: tuple[float, float, float]
    gravity: float = C.GRAVITY

    def inertia_tensor(self, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> torch.Tensor:
        """(3, 3) inertia as a tensor."""
        return constant_tensor(tuple(map(tuple, self.inertia_b)), dtype, device)


@functools.lru_cache(maxsize=1)
def robot_srbd_model() -> SRBDModel:
    """Whole-robot SRBD parameters from the MJCF at the ``home`` keyframe (MuJoCo, cached).

    The inertia is the composite inertia of all bodies about the whole-robot CoM, expressed
    in the base frame: sum_b R_b I_b R_b^T + m_b (|r_b|^2 1 - r_b r_b^T), r_b = CoM_b - CoM.
    The mass is ``constants.TOTAL_MASS`` (the MJCF is generated from the same numbers).
    """
    import mujoco  # local: keep `import dls_quadruped.mpc` light

    model = mujoco.MjModel.from_xml_path(str(C.MJCF_PATH))
    data = mujoco.MjData(model)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    mujoco.mj_resetDataKeyframe(model, data, key)
    mujoco.mj_forward(model, data)
    trunk = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    com_w = data.subtree_com[trunk].copy()
    inertia_w = np.zeros((3, 3))
    for b in range(1, model.nbody):  # body 0 is the world
        m_b = model.body_mass[b]
        rot = data.ximat[b].reshape(3, 3)  # principal inertia axes -> world
        r = data.xipos[b] - com_w
        inertia_w += rot @ np.diag(model.body_inertia[b]) @ rot.T + m_b * (r @ r * np.eye(3) - np.outer(r, r))
    rot_base = data.xmat[trunk].reshape(3, 3)  # base -> world
    inertia_b = rot_base.T @ inertia_w @ rot_base
    com_offset_b = rot_base.T @ (com_w - data.xpos[trunk])
    return SRBDModel(
        mass=float(C.TOTAL_MASS),
        inertia_b=tuple(tuple(float(v) for v in row) for row in inertia_b),
        com_offset_b=tuple(float(v) for v in com_offset_b),
        gravity=float(C.GRAVITY),
    )


def com_height_reference(model: SRBDModel | None = None) -> float:
    """The MPC's CoM height reference above flat ground [m] (~0.324 m).

    The base at ``constants.BASE_HEIGHT_TARGET`` (the RL task's height target too: the reward's
    proprioceptive target is that minus the foot radius), level, so the CoM sits ``com_offset_b[2]``
    (~ -13.5 mm) below it: z_c = z_b + (R c_b)_z with R = 1.
    """
    model = model if model is not None else robot_srbd_model()
    return float(C.BASE_HEIGHT_TARGET + model.com_offset_b[2])


# ----------------------------------------------------------------------------------------------
# Euler angles
# ----------------------------------------------------------------------------------------------


def rotation_from_euler(euler: torch.Tensor) -> torch.Tensor:
    """Body -> world rotation R = Rz(yaw) Ry(pitch) Rx(roll).

    Args:
        euler: (..., 3) [rad] (roll, pitch, yaw).

    Returns:
        (..., 3, 3).
    """
    cr, cp, cy = torch.cos(euler).unbind(-1)
    sr, sp, sy = torch.sin(euler).unbind(-1)
    rows = (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def euler_rate_matrix_inv(euler: torch.Tensor) -> torch.Tensor:
    """E'^-1(Phi) of eq. C.2.3: Phi_dot = E'^-1 omega_b.

    Args:
        euler: (..., 3) [rad] (roll, pitch, yaw).

    Returns:
        (..., 3, 3); singular at pitch = +-90 deg (gimbal lock, not handled: locomotion stays flat).
    """
    cr, cp, _ = torch.cos(euler).unbind(-1)
    sr, sp, _ = torch.sin(euler).unbind(-1)
    one, zero = torch.ones_like(cr), torch.zeros_like(cr)
    rows = (
        (one, sr * sp / cp, cr * sp / cp),
        (zero, cr, -sr),
        (zero, sr / cp, cr / cp),
    )
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


# ----------------------------------------------------------------------------------------------
# State
# ----------------------------------------------------------------------------------------------


@dataclass
class SRBDState:
    """Batched SRBD state of B robots (float32, one device).

    Attributes:
        com_pos_w: (B, 3) [m] CoM position, world.
        com_vel_w: (B, 3) [m/s] CoM velocity, world.
        euler: (B, 3) [rad] (roll, pitch, yaw), R = Rz Ry Rx body -> world.
        ang_vel_b: (B, 3) [rad/s] angular velocity, base frame.
        foot_pos_w: (B, 4, 3) [m] foot positions (sphere centres), world.
    """

    com_pos_w: torch.Tensor
    com_vel_w: torch.Tensor
    euler: torch.Tensor
    ang_vel_b: torch.Tensor
    foot_pos_w: torch.Tensor

    @property
    def batch_size(self) -> int:
        """B."""
        return self.com_pos_w.shape[0]

    def validate(self) -> None:
        """Raise ValueError naming the field whose shape is not as documented."""
        if not isinstance(self.com_pos_w, torch.Tensor) or self.com_pos_w.dim() != 2:
            raise ValueError(f"SRBDState.com_pos_w must be a (B, 3) tensor, got "
                             f"{getattr(self.com_pos_w, 'shape', None)}")
        b = self.com_pos_w.shape[0]
        expected = {"com_pos_w": (b, 3), "com_vel_w": (b, 3), "euler": (b, 3), "ang_vel_b": (b, 3),
                    "foot_pos_w": (b, NUM_LEGS, 3)}
        for name, shape in expected.items():
            value = getattr(self, name)
            if not isinstance(value, torch.Tensor) or tuple(value.shape) != shape:
                raise ValueError(f"SRBDState.{name} must have shape {shape} (B = {b}), got "
                                 f"{tuple(getattr(value, 'shape', ()))}")

    def as_vector(self) -> torch.Tensor:
        """(B, 24) in the order [p_c, v_c, Phi, omega_b, p_f (leg-major)]."""
        return torch.cat([self.com_pos_w, self.com_vel_w, self.euler, self.ang_vel_b,
                          self.foot_pos_w.reshape(-1, 3 * NUM_LEGS)], dim=-1)

    @classmethod
    def from_vector(cls, x: torch.Tensor) -> SRBDState:
        """Inverse of :meth:`as_vector`; x: (B, 24)."""
        return cls(x[:, 0:3], x[:, 3:6], x[:, 6:9], x[:, 9:12], x[:, 12:24].reshape(-1, NUM_LEGS, 3))

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> SRBDState:
        """Copy on another device/dtype."""
        return SRBDState(**{f.name: getattr(self, f.name).to(device=device, dtype=dtype) for f in fields(self)})

    def finite_mask(self) -> torch.Tensor:
        """(B,) bool, True where every entry of the robot's state is finite."""
        return torch.isfinite(self.as_vector()).all(dim=-1)


def srbd_state_from_base(
    base_pos_w: torch.Tensor,
    base_quat_w: torch.Tensor,
    base_lin_vel_w: torch.Tensor,
    base_ang_vel_b: torch.Tensor,
    foot_pos_w: torch.Tensor,
    model: SRBDModel | None = None,
) -> SRBDState:
    """SRBD state from the base pose/velocity (e.g. a :class:`RobotState`) and the feet.

    p_c = p_base + R c_b and v_c = v_base + R (omega_b x c_b), with c_b the CoM offset in the
    base frame (rigid-body assumption: leg motion ignored).

    Args:
        base_pos_w: (B, 3) [m]; base_quat_w: (B, 4) (w, x, y, z) base -> world;
        base_lin_vel_w: (B, 3) [m/s] base origin velocity, world; base_ang_vel_b: (B, 3) [rad/s];
        foot_pos_w: (B, 4, 3) [m].
        model: SRBD parameters (default: :func:`robot_srbd_model`).
    """
    model = model or robot_srbd_model()
    dtype, device = base_pos_w.dtype, base_pos_w.device
    euler = euler_from_quat(base_quat_w)
    rot = rotation_from_euler(euler)  # (B, 3, 3) base -> world
    c_b = constant_tensor(tuple(model.com_offset_b), dtype, device).expand_as(base_pos_w)
    com_pos_w = base_pos_w + (rot @ c_b.unsqueeze(-1)).squeeze(-1)
    com_vel_w = base_lin_vel_w + (rot @ torch.cross(base_ang_vel_b, c_b, dim=-1).unsqueeze(-1)).squeeze(-1)
    return SRBDState(com_pos_w, com_vel_w, euler, base_ang_vel_b.clone(), foot_pos_w.clone())


def srbd_state_from_robot_state(robot_state, model: SRBDModel | None = None) -> SRBDState:
    """:func:`srbd_state_from_base` applied to a :class:`dls_quadruped.core.state.RobotState` (B robots)."""
    rs = robot_state
    return srbd_state_from_base(rs.base_pos_w, rs.base_quat_w, rs.base_lin_vel_w, rs.base_ang_vel_b, rs.foot_pos_w,
                                model)


# ----------------------------------------------------------------------------------------------
# Reference (plain eager) rollout
# ----------------------------------------------------------------------------------------------


def srbd_step(
    x: torch.Tensor, contact: torch.Tensor, foot_target_w: torch.Tensor, force_w: torch.Tensor,
    model: SRBDModel, dt: float,
) -> torch.Tensor:
    """One explicit-Euler step of the SRBD, straightforward batched torch.

    Args:
        x: (..., 24) state.
        contact: (..., 4) 0/1 (or bool) stance flags.
        foot_target_w: (..., 4, 3) [m] touch-down targets, world.
        force_w: (..., 4, 3) [N] ground-reaction forces, world.
        model: SRBD parameters.
        dt: [s].

    Returns:
        (..., 24) next state.
    """
    dtype, device = x.dtype, x.device
    p, v, euler, omega = x[..., 0:3], x[..., 3:6], x[..., 6:9], x[..., 9:12]
    feet = x[..., 12:24].unflatten(-1, (NUM_LEGS, 3))
    c = contact.to(dtype).unsqueeze(-1)  # (..., 4, 1)
    inertia = model.inertia_tensor(dtype, device)
    gravity = constant_tensor((0.0, 0.0, -model.gravity), dtype, device)
    f_c = c * force_w  # (..., 4, 3) forces of the stance legs
    acc = gravity + f_c.sum(-2) / model.mass
    torque_w = torch.cross(feet - p.unsqueeze(-2), f_c, dim=-1).sum(-2)  # (p_f - p_c) x F
    rot = rotation_from_euler(euler)
    torque_b = (rot.transpose(-1, -2) @ torque_w.unsqueeze(-1)).squeeze(-1)
    i_omega = omega @ inertia.T
    omega_dot = (torque_b - torch.cross(omega, i_omega, dim=-1)) @ torch.linalg.inv(inertia).T
    euler_dot = (euler_rate_matrix_inv(euler) @ omega.unsqueeze(-1)).squeeze(-1)
    feet_next = c * feet + (1 - c) * foot_target_w  # eq. C.1.4
    return torch.cat([p + dt * v, v + dt * acc, euler + dt * euler_dot, omega + dt * omega_dot,
                      feet_next.flatten(-2)], dim=-1)


def rollout_reference(
    x0: torch.Tensor, contact: torch.Tensor, foot_target_w: torch.Tensor, force_w: torch.Tensor,
    model: SRBDModel, dt: float,
) -> torch.Tensor:
    """Roll the SRBD out over N steps (Python loop over steps only).

    Args:
        x0: (B, 24) initial state, broadcast over samples.
        contact: (B, M, N, 4); foot_target_w: (B, M, N, 4, 3); force_w: (B, M, N, 4, 3).

    Returns:
        (B, M, N + 1, 24) states x_0 .. x_N.
    """
    b, m, n = contact.shape[:3]
    x = x0[:, None, :].expand(b, m, STATE_DIM)
    states = [x]
    for k in range(n):
        x = srbd_step(x, contact[:, :, k], foot_target_w[:, :, k], force_w[:, :, k], model, dt)
        states.append(x)
    return torch.stack(states, dim=2)
