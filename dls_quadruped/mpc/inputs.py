"""What one sampling-MPC solve sees, built from the robot state: the SRBD state, the cost references, the
horizontal frame H and the ground the MPC plans on. Every MPC controller (the model-based baseline, the
warm-started MPC of the closed loop) and the closed loop's initial-cost probe build their inputs here.

* footholds: the heuristic planner of eq. 2.2.4, in frame H relative to the nominal foothold under the hip::

      p_h = T_stance / 2 * v_ref + sqrt(z_com / g) (v - v_ref),   T_stance = d / f

* references: CoM height ``com_height`` above the ground, the commanded planar velocity turned into the world
  frame, the commanded yaw rate, flat attitude, the footholds above in the world frame;
* ground (``GROUNDS``): z = 0, flat at the height the stance feet stand on, or the terrain map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from dls_quadruped.control.latent_action import TerrainHeightFn
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.core.state import RobotState
from dls_quadruped.core.torch_cache import constant_tensor
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.srbd import srbd_state_from_base
from dls_quadruped.robots.aliengo import constants as C

if TYPE_CHECKING:
    from dls_quadruped.mpc.baseline import BaselineConfig

GROUNDS = ("flat", "stance_feet", "terrain")
"""Ground the MPC plans on: ``flat`` = z = 0 (the simple task); ``stance_feet`` = flat at the height its stance
feet stand on (:func:`stance_ground_z`, terrain-blind: no map, as in the thesis); ``terrain`` = the env's terrain
map (``env.scene.terrain.height_at``, past the thesis): the CoM reference above the terrain under the base, each
leg's touch-down at the terrain height under its reference foothold (:func:`mpc_inputs`)."""


def heuristic_footholds_h(state: RobotState, cmd_vel_h: torch.Tensor, cfg: BaselineConfig) -> torch.Tensor:
    """Eq. 2.2.4 in frame H: (B, 4, 2) [m] offsets from the nominal foothold under each hip.

    Args:
        state: robot state (B robots).
        cmd_vel_h: (B, 3) commanded (v_x, v_y) [m/s] in frame H and yaw rate [rad/s].
        cfg: the gait (``freq`` [Hz], ``duty``) and ``com_height`` [m] (``mpc.baseline.BaselineConfig``).
    """
    yaw = rpy_from_rotmat(quat_to_rotmat(state.base_quat_w.double()))[:, 2]
    c, s = torch.cos(yaw), torch.sin(yaw)
    v_w = state.base_lin_vel_w.double()
    v_h = torch.stack([c * v_w[:, 0] + s * v_w[:, 1], -s * v_w[:, 0] + c * v_w[:, 1]], dim=-1)  # (B, 2)
    v_ref = cmd_vel_h[:, :2].double()
    t_stance = cfg.duty / cfg.freq
    k = (cfg.com_height / C.GRAVITY) ** 0.5
    p_h = t_stance / 2 * v_ref + k * (v_h - v_ref)  # (B, 2), the same for every leg
    return p_h.unsqueeze(1).expand(-1, 4, 2).float()


def mpc_inputs(state: RobotState, cmd_vel_h: torch.Tensor, p_h: torch.Tensor, com_height: float,
               sampler: SamplerConfig, model, ground_z: torch.Tensor | None = None,
               height_fn: TerrainHeightFn | None = None) -> tuple:
    """The SRBD state, the cost references and the horizontal frame of one solve.

    Args:
        state: robot state (B robots); cmd_vel_h: (B, 3) command (v_x, v_y [m/s] in frame H, yaw rate [rad/s]);
        p_h: (B, 4, 2) [m] reference footholds relative to the nominal ones (eq. 2.2.4);
        com_height: [m] CoM height reference above the ground;
        ground_z: (B,) [m] height of the flat ground the MPC assumes under each robot (None: z = 0):
            the CoM reference, the reference footholds and the touch-downs are placed on it.
        height_fn: the terrain map ``(x_w, y_w) -> z_w`` (``Terrain.height_at``), instead of ``ground_z``:
            the CoM reference is ``com_height`` above the terrain under the base, and each leg's reference
            foothold and touch-down height is the terrain under that leg's reference foothold (the kernel
            takes one height per leg for the whole horizon: ``SamplingMPC.solve``'s ``terrain_z_w``).

    Returns:
        (SRBDState, Refs, {"base_xy_w": (B, 2), "base_yaw": (B,)[, "terrain_z_w": (B, 4) with a ground]}).
    """
    if ground_z is not None and height_fn is not None:
        raise ValueError("mpc_inputs: give ground_z (flat ground) or height_fn (terrain map), not both")
    b = state.base_pos_w.shape[0]
    srbd = srbd_state_from_base(state.base_pos_w, state.base_quat_w, state.base_lin_vel_w,
                                state.base_ang_vel_b, state.foot_pos_w, model)
    yaw = srbd.euler[:, 2]
    c, s = torch.cos(yaw), torch.sin(yaw)
    cmd = cmd_vel_h.float()
    v_ref_w = torch.stack([c * cmd[:, 0] - s * cmd[:, 1], s * cmd[:, 0] + c * cmd[:, 1]], dim=-1)
    nominal = constant_tensor(tuple(map(tuple, sampler.action.nominal_foothold_b)), torch.float32, p_h.device) + p_h
    base_xy = state.base_pos_w[:, :2].float()
    foothold_w = torch.stack([
        base_xy[:, None, 0] + c[:, None] * nominal[..., 0] - s[:, None] * nominal[..., 1],
        base_xy[:, None, 1] + s[:, None] * nominal[..., 0] + c[:, None] * nominal[..., 1],
        torch.full_like(nominal[..., 0], C.FOOT_RADIUS),
    ], dim=-1)
    frame = {"base_xy_w": base_xy, "base_yaw": yaw}
    com_ref = torch.full((b,), float(com_height), device=base_xy.device)
    if ground_z is not None:
        z = ground_z.float()
        com_ref = com_ref + z
        foothold_w = torch.cat([foothold_w[..., :2], foothold_w[..., 2:] + z[:, None, None]], dim=-1)
        frame["terrain_z_w"] = z[:, None].expand(b, 4).contiguous()
    elif height_fn is not None:
        com_ref = com_ref + height_fn(base_xy[:, 0], base_xy[:, 1]).float()  # terrain under the base
        xy = foothold_w[..., :2].float()
        z_legs = height_fn(xy[..., 0], xy[..., 1]).float()  # (B, 4) under the reference footholds
        foothold_w = torch.cat([foothold_w[..., :2], foothold_w[..., 2:] + z_legs[..., None]], dim=-1)
        frame["terrain_z_w"] = z_legs.contiguous()
    refs = Refs(com_height_w=com_ref, lin_vel_w=v_ref_w, yaw_rate=cmd[:, 2].clone(), foothold_w=foothold_w)
    return srbd, refs, frame


def stance_ground_z(state: RobotState) -> torch.Tensor:
    """(B,) [m] a blind robot's estimate of the ground under it: the mean height of the commanded stance
    feet less the foot radius (all four feet when none is in stance). No terrain map: on a step or a slope
    the MPC still plans on flat ground, at the height its feet stand on (what leg odometry gives)."""
    foot_z = state.foot_pos_w[..., 2].float() - C.FOOT_RADIUS
    stance = state.contact_cmd.bool()
    none = ~stance.any(dim=-1, keepdim=True)
    w = (stance | none).float()
    return (foot_z * w).sum(-1) / w.sum(-1)


def ground_inputs(ground: str, state: RobotState, height_fn: TerrainHeightFn | None = None) -> dict:
    """The :func:`mpc_inputs` / ``ModelBasedBaseline.step`` keywords of one ground (one of ``GROUNDS``): the one
    place the MPC controllers and the initial-cost probe turn a ground name into what the solve sees.

    Args:
        state: robot state (B robots); height_fn: ``(x_w, y_w) -> z_w`` the terrain map, needed for ``terrain``.

    Returns:
        {} for ``flat``, {"ground_z": (B,)} for ``stance_feet``, {"height_fn": height_fn} for ``terrain``.
    """
    if ground == "flat":
        return {}
    if ground == "stance_feet":
        return {"ground_z": stance_ground_z(state)}
    if ground == "terrain":
        if height_fn is None:
            raise ValueError("ground 'terrain' needs the terrain map (env.scene.terrain.height_at)")
        return {"height_fn": height_fn}
    raise ValueError(f"ground must be one of {list(GROUNDS)}, got {ground!r}")
