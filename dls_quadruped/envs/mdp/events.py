"""Event terms (thesis 4.3.2): ``event(env, env_mask, **params)``, applied to the robots of ``env_mask``.

``env_mask`` is a (B,) bool mask: a term computes its values for every robot and the backend keeps the masked rows
(``sim/interface.py``), so a step with resets and pushes has static shapes and reads nothing back to the host.
Modes (set per term in the task file): ``startup`` (once, all envs), ``reset`` (envs being reset),
``interval`` (per-env timer drawn from ``interval_s``). "High" values are in ``tasks/rough.yaml``;
"low" ones (one third of the variation) in ``tasks/_low_perturbation.yaml``.
Every draw comes from the env's episode schedule (one stream per term function, ``envs/schedule.py``); the event
manager calls a term inside ``schedule.only(env_mask)``, so only the masked robots' draws count, and they are the
numbers a draw of those robots alone would give.
"""

from __future__ import annotations

import functools
import math

import mujoco
import torch

from dls_quadruped.core.rotations import quat_from_yaw
from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import home_state


def _uniform(env, shape: tuple[int, ...], rng, stream: str) -> torch.Tensor:
    """(B, *shape) U[rng) of every env from the env's episode schedule."""
    ids = torch.arange(env.num_envs, device=env.device)
    return env.schedule.uniform(ids, shape, float(rng[0]), float(rng[1]), stream=stream)


_CONSTANTS = {name: value.tolist() for name, value in vars(C).items() if name.isupper() and hasattr(value, "tolist")}
_CONSTANTS["THIGH_Y"] = (C.LEG_Y_SIGN * C.THIGH_OFFSET_Y).tolist()
"""The robot's numpy constants as Python numbers: a numpy value read inside a compiled function becomes a graph
input (and a guard that fails between inference mode and grad mode)."""


@constant_cache
def _constant(name: str, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The robot constant ``name`` of the ``constants`` module (or ``"THIGH_Y"``, the signed lateral thigh offsets
    (4,) [m]) as a tensor, built once per dtype and device (a per-reset upload is a host-to-device copy on a
    GPU); read-only."""
    return torch.as_tensor(_CONSTANTS[name], dtype=dtype, device=device)


def foot_positions_b(q: torch.Tensor) -> torch.Tensor:
    """(n, 4, 3) foot sphere centres in the base frame [m] of joint positions ``q`` (n, 12): hip about x at
    ``HIP_OFFSETS_B``, thigh offset ``+-THIGH_OFFSET_Y`` along the hip's y, thigh and calf about y."""
    legs = q.reshape(-1, C.NUM_LEGS, 3)
    q0, q1, q12 = legs[..., 0], legs[..., 1], legs[..., 1] + legs[..., 2]
    px = -C.THIGH_LENGTH * torch.sin(q1) - C.CALF_LENGTH * torch.sin(q12)  # leg plane, before the hip roll
    pz = -C.THIGH_LENGTH * torch.cos(q1) - C.CALF_LENGTH * torch.cos(q12)
    py = _constant("THIGH_Y", q.dtype, q.device)
    hip = _constant("HIP_OFFSETS_B", q.dtype, q.device)
    c, s = torch.cos(q0), torch.sin(q0)
    return hip + torch.stack([px, py * c - pz * s, py * s + pz * c], dim=-1)


def spawn_height(terrain, xy: torch.Tensor, yaw: torch.Tensor, q: torch.Tensor, height: float) -> torch.Tensor:
    """(n,) base z [m]: ``height`` above the terrain under the base, raised where a foot of joint pose ``q``
    would otherwise start lower than the nominal pose's feet on flat ground (a leg straightened by the reset's
    joint scale, or a foot over a bump or a higher step): its sphere then starts ``height -
    STANDING_BASE_HEIGHT`` above the terrain under it. Feet inside the ground at the first step are pushed out
    by the contact solver in one step and throw the robot (75 % of rough-task resets did with 0.8-1.2 joint
    scales). The nominal pose on flat ground gives ``height`` exactly."""
    feet = foot_positions_b(q)
    c, s = torch.cos(yaw)[:, None], torch.sin(yaw)[:, None]
    fx = xy[:, 0:1] + c * feet[..., 0] - s * feet[..., 1]
    fy = xy[:, 1:2] + s * feet[..., 0] + c * feet[..., 1]
    nominal = foot_positions_b(_constant("NOMINAL_JOINT_POS", q.dtype, q.device)[None])
    ground = terrain.height_at(xy[:, 0], xy[:, 1])
    lowest = (terrain.height_at(fx, fy) - feet[..., 2]).amax(dim=1)  # the base z at which the lowest foot's
    raise_by = lowest - (ground - nominal[0, :, 2].amin())           # centre meets its ground, vs nominal/flat
    return ground + height + raise_by.clamp(min=0.0)


def reset_robot(env, env_mask: torch.Tensor, joint_scale: tuple[float, float] = (1.0, 1.0),
                yaw: tuple[float, float] = (-math.pi, math.pi), xy_offset: float = 0.0,
                height: float = float(C.STANDING_BASE_HEIGHT + 0.02)) -> None:
    """Place robots on their terrain origin: random yaw, xy offset within +-``xy_offset`` [m],
    joints = nominal x U(joint_scale) (0.8-1.2 in "high"), base ``height`` [m] above the terrain, higher
    where a foot would start inside the terrain (``spawn_height``). The placement of every robot is one compiled
    function where the scene compiles (``scene.compile``); the backend resets the masked robots."""
    placement = env.fused(_placement, "reset_robot placement", eager_first=True)  # its draws' streams made first
    env.scene.reset_robots(env_mask, *placement(env, joint_scale, yaw, xy_offset, height))


def _placement(env, joint_scale: tuple[float, float], yaw: tuple[float, float], xy_offset: float,
               height: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``reset_robot``'s base positions (B, 3), orientations (B, 4) and joint positions (B, 12) of every robot."""
    dev = env.device
    origins = env.scene.env_origins
    xy = origins[:, :2] + _uniform(env, (2,), (-xy_offset, xy_offset), "reset_robot")
    nominal = _constant("NOMINAL_JOINT_POS", torch.float32, dev)
    q = nominal * _uniform(env, (12,), joint_scale, "reset_robot")
    lim = _constant("JOINT_RANGES", torch.float32, dev)
    q = torch.clamp(q, lim[:, 0], lim[:, 1])
    heading = _uniform(env, (), yaw, "reset_robot")
    z = spawn_height(env.scene.terrain, xy, heading, q, height)
    return torch.cat([xy, z[:, None]], dim=-1), quat_from_yaw(heading), q


def reset_home(env, env_mask: torch.Tensor, joint_noise: float = 0.0, yaw: float | list[float] = 0.0,
               origin_xy: list[float] = (0.0, 0.0), seed: int = 0) -> None:
    """Place robots in the home pose of ``sim.interface.home_state``: base ``STANDING_BASE_HEIGHT + 5 mm`` above
    z = 0 at ``origin_xy`` (x, y) [m] (a flat patch), heading ``yaw`` [rad] (one for all envs or one per env),
    joints nominal + U(-joint_noise, joint_noise) [rad] from a generator seeded with ``seed`` for every env at
    once (not the episode schedule: a restarted robot starts from its first pose again). The start of the balance
    controller's and the model-based baseline's runs (``envs/home_task.py``); list it before other reset events
    (a backend reset clears the base wrench). ``origin_xy`` is a point, not a ``[low, high]`` range."""
    if len(origin_xy) != 2:
        raise ValueError(f"reset_home: origin_xy must be (x, y) [m], got {origin_xy!r}")
    yaw_key = tuple(float(y) for y in yaw) if isinstance(yaw, (list, tuple)) else float(yaw)
    pos, quat, joints = _home_rows(env.num_envs, seed, float(joint_noise), yaw_key,
                                   tuple(float(x) for x in origin_xy), env.device)
    env.scene.reset_robots(env_mask, pos, quat, joints)


@functools.lru_cache(maxsize=16)
def _home_rows(num: int, seed: int, joint_noise: float, yaw: float | tuple[float, ...], origin_xy: tuple[float, float],
               device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``reset_home``'s base positions (num, 3), orientations (num, 4) and joints (num, 12), float64 on ``device``,
    built once per set of parameters (a reset then uploads nothing); read-only."""
    home = home_state(num, seed, joint_noise, torch.tensor(yaw, dtype=torch.float64) if isinstance(yaw, tuple) else yaw)
    pos = home["base_pos_w"] + torch.tensor([*origin_xy, 0.0], dtype=torch.float64)
    return pos.to(device), home["base_quat_w"].to(device), home["joint_pos"].to(device)


PLACEMENT_EVENTS = (reset_robot, reset_home)
"""The reset events that place robots; an env needs one of them in ``reset`` mode."""


def randomize_friction(env, env_mask: torch.Tensor, friction_range: tuple[float, float]) -> None:
    """Sliding friction of the foot-ground contacts, U(friction_range) per env.

    MuJoCo has one Coulomb coefficient per contact, so the thesis' static/dynamic pair (mu_s in
    [0.6, 0.8], mu_d in [0.4, 0.6]) maps to one mu in [0.4, 0.8] ("high"). The feet have contact
    priority 1, so a foot contact takes the foot geom's coefficient whatever the ground's: the
    value is written to the four foot geoms (``scene.friction_geom_ids``).
    """
    ids = env.scene.friction_geom_ids
    mu = _uniform(env, (), friction_range, "randomize_friction")
    nominal = torch.as_tensor(env.scene.model.geom_friction[ids], dtype=torch.float64, device=mu.device)
    values = nominal.expand(env.num_envs, *nominal.shape).clone()  # (B, 4, 3)
    values[:, :, 0] = mu[:, None]
    env.scene.sim.set_model_field("geom_friction", env_mask, values, index=ids)


def randomize_base_mass(env, env_mask: torch.Tensor, scale_range: tuple[float, float]) -> None:
    """Robot mass x U(scale_range) per env (Table 3: 0.85-1.15 "high", 0.95-1.05 speed/"low").

    The scale is of the whole robot's mass (24.64 kg), as Table 3 states, and the difference is
    carried by the trunk (a payload): trunk mass + (s - 1) m_robot. The controller keeps the
    nominal model.
    """
    model = env.scene.model
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    scale = _uniform(env, (), scale_range, "randomize_base_mass")
    nominal = torch.as_tensor(model.body_mass, dtype=torch.float64, device=scale.device)
    values = nominal.expand(env.num_envs, *nominal.shape).clone()  # (B, nbody)
    robot_mass = float(model.body_subtreemass[bid])
    values[:, bid] += (scale - 1.0) * robot_mass
    env.scene.sim.set_model_field("body_mass", env_mask, values)


def external_wrench(env, env_mask: torch.Tensor, force_range: tuple[float, float],
                    torque_range: tuple[float, float]) -> None:
    """Constant force [N] and torque [N m] on the base, each world component U(range), until the next call."""
    force = _uniform(env, (3,), force_range, "external_wrench")
    torque = _uniform(env, (3,), torque_range, "external_wrench")
    env.scene.sim.set_external_wrench(env_mask, force, torque)


def push_robot(env, env_mask: torch.Tensor, velocity_range: tuple[float, float]) -> None:
    """Push: add U(velocity_range) [m/s] to the base x and y velocity (world frame)."""
    v = env.state.base_lin_vel_w.clone()
    v[:, :2] += _uniform(env, (2,), velocity_range, "push_robot")
    env.scene.sim.set_base_velocity(env_mask, v)
