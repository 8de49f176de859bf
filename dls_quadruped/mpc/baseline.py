"""Model-based baseline (thesis Fig. 1): periodic trot + heuristic footholds + sampling MPC on the forces.

At every MPC step (100 Hz) for B robots:

1. gait: fixed periodic trot (f, d); the MPC's sigma_f = sigma_d = 0;
2. footholds: the heuristic planner of eq. 2.2.4, in the horizontal frame H relative to the
   nominal foothold under the hip::

       p_h = T_stance / 2 * v_ref + sqrt(z_com / g) (v - v_ref),   T_stance = d / f

   (sigma_p = 0: the MPC does not change them; they are also the cost's foothold reference);
3. forces: the sampling MPC searches around the naive warm start alone (the thesis's naive
   controller): the previous solution with its swing-step force offsets zeroed, shifted by one MPC
   period, with the gait and footholds of steps 1-2 written into it. Forces are sampled as offsets
   from gravity compensation m g / (stance legs of each step) (``samples.forces_from_offsets``), so
   this is a meaningful controller on its own. Optionally (``anchor_share > 0``, off in the thesis
   experiments) a share of the samples is drawn around the nominal trot (zero offsets) as well;
4. the first action ``(f, d, p_0, F_0)`` goes to the low-level controller, which runs at 200 Hz
   inside the simulator backend for ``mpc_period / physics_dt`` physics steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import mujoco
import numpy as np
import torch

from dls_quadruped.control.latent_action import TerrainHeightFn
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.core.state import RobotState
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.encodings import block_slices, fit_spline
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC
from dls_quadruped.mpc.srbd import com_height_reference, srbd_state_from_base
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend


@dataclass(frozen=True)
class BaselineConfig:
    """Model-based baseline settings.

    Attributes:
        freq, duty: periodic trot [Hz], stance fraction.
        com_height: desired CoM height above the ground [m]; default :func:`srbd.com_height_reference` (the
            base at ``constants.BASE_HEIGHT_TARGET``, the RL task's height target, ~0.324 m for the CoM).
        anchor_share: share of the samples drawn around the nominal trot (zero force offsets) besides
            the naive warm start; 0 (default, the thesis's naive controller) = naive warm start alone.
            Before forces were sampled as offsets from gravity compensation, the naive warm start
            alone collapsed the robot within 0.5 s and a 0.2 anchor share was needed.
        sampler: sampling-MPC settings; sigma_f, sigma_d and sigma_p are forced to 0 (forces only).
    """

    freq: float = 1.5
    duty: float = 0.6
    com_height: float = field(default_factory=com_height_reference)
    anchor_share: float = 0.0
    optimise: tuple[str, ...] = ("F",)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)

    def __post_init__(self) -> None:
        if not 0.0 <= self.anchor_share < 1.0:
            raise ValueError(f"BaselineConfig.anchor_share must be in [0, 1), got {self.anchor_share!r}")
        check_optimise(self.optimise)

    def forces_only(self) -> SamplerConfig:
        """The sampler config with gait and foothold optimisation switched off."""
        return replace(self.sampler, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)

    def optimised_sampler(self) -> SamplerConfig:
        """The sampler config with sigma = 0 on every variable not in ``optimise`` (thesis 7.3: F only)."""
        return optimised(self.sampler, self.optimise)


OPTIMISABLE = ("f", "d", "p", "F")
"""Variables the sampling MPC can optimise (thesis 7.3.1: F by default; 7.3.5: f and d; 7.3.6: p)."""


def check_optimise(optimise: tuple[str, ...]) -> None:
    """Raise ``ValueError`` unless ``optimise`` is a non-empty tuple of distinct names from ``OPTIMISABLE``."""
    if (not isinstance(optimise, tuple) or not optimise or len(set(optimise)) != len(optimise)
            or any(v not in OPTIMISABLE for v in optimise)):
        raise ValueError(f"optimise must be a non-empty tuple of distinct variables from {OPTIMISABLE}, got {optimise!r}")


def optimised(sampler: SamplerConfig, optimise: tuple[str, ...]) -> SamplerConfig:
    """``sampler`` with sigma = 0 on every variable not in ``optimise``."""
    check_optimise(optimise)
    return replace(sampler, **{f"sigma_{v}": 0.0 for v in OPTIMISABLE if v not in optimise})


def heuristic_footholds_h(state: RobotState, cmd_vel_h: torch.Tensor, cfg: BaselineConfig) -> torch.Tensor:
    """Eq. 2.2.4 in frame H: (B, 4, 2) [m] offsets from the nominal foothold under each hip.

    Args:
        state: robot state (B robots).
        cmd_vel_h: (B, 3) commanded (v_x, v_y) [m/s] in frame H and yaw rate [rad/s].
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


class ModelBasedBaseline:
    """Trot + heuristic footholds + force-only sampling MPC for B robots (see module docstring)."""

    def __init__(self, num_robots: int, cfg: BaselineConfig = BaselineConfig(), device: str = "cpu", seed: int = 0):
        self.cfg = cfg
        self.sampler_cfg = cfg.optimised_sampler()
        self.mpc = SamplingMPC(self.sampler_cfg, device=device, seed=seed)
        self.num_robots = num_robots
        self.slices = block_slices(self.sampler_cfg.encoding)
        self.default = warm_start.nominal_trot(num_robots, self.sampler_cfg, cfg.freq, cfg.duty)

    def _encode_p(self, p_h: torch.Tensor) -> torch.Tensor:
        """The p block of the encoding for footholds held over the horizon, (B, 4, 2) -> (B, Dp)."""
        kind, horizon = self.sampler_cfg.encoding.p, self.sampler_cfg.horizon
        flat = p_h.reshape(self.num_robots, 8)
        if kind == "first":
            return flat
        if kind == "discrete":
            return flat.repeat(1, horizon)
        return fit_spline(flat[:, None, :].expand(-1, horizon, 8), constrained=True).reshape(self.num_robots, -1)

    def step(self, state: RobotState, cmd_vel_h: torch.Tensor, ground_z: torch.Tensor | None = None,
             height_fn: TerrainHeightFn | None = None) -> tuple[MPCResult, Refs]:
        """One MPC solve: returns the result (first action in the world frame) and the references used.

        The warm start is the naive one (previous solution shifted); the blocks that are not optimised
        are overwritten with the periodic trot (f, d) and the heuristic footholds (p). An optimised
        block keeps the previous solution's values (the trot and the heuristic footholds at the first solve).
        """
        cfg = self.cfg
        p_h = heuristic_footholds_h(state, cmd_vel_h, cfg)
        p_block = self._encode_p(p_h)
        first = self.mpc.last_result is None
        warm_starts = [self.mpc.naive_warm_start(self.default).clone()]
        proportions: tuple[float, ...] = (1.0,)
        if cfg.anchor_share > 0.0:
            warm_starts.append(self.default.clone())
            proportions = (1.0 - cfg.anchor_share, cfg.anchor_share)
        for w in warm_starts:
            if "f" not in cfg.optimise:
                w[:, self.slices["f"]] = cfg.freq
            if "d" not in cfg.optimise:
                w[:, self.slices["d"]] = cfg.duty
            if "p" not in cfg.optimise or first:
                w[:, self.slices["p"]] = p_block
        srbd, refs, frame = mpc_inputs(state, cmd_vel_h, p_h, cfg.com_height, self.sampler_cfg, self.mpc.model,
                                       ground_z, height_fn)
        result = self.mpc.solve(srbd, refs, warm_starts=warm_starts, proportions=proportions,
                                phase=state.phase, **frame)
        return result, refs


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
    nominal = torch.tensor(sampler.action.nominal_foothold_b, dtype=torch.float32) + p_h  # (B, 4, 2)
    base_xy = state.base_pos_w[:, :2].float()
    foothold_w = torch.stack([
        base_xy[:, None, 0] + c[:, None] * nominal[..., 0] - s[:, None] * nominal[..., 1],
        base_xy[:, None, 1] + s[:, None] * nominal[..., 0] + c[:, None] * nominal[..., 1],
        torch.full_like(nominal[..., 0], C.FOOT_RADIUS),
    ], dim=-1)
    frame = {"base_xy_w": base_xy, "base_yaw": yaw}
    com_ref = torch.full((b,), float(com_height))
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


@dataclass
class BaselineRun:
    """Recorded signals of a closed-loop baseline run, one row per MPC step (robot 0..B-1).

    Attributes:
        time: (T,) [s]; base_vel_w: (T, B, 3) [m/s]; base_height: (T, B) [m];
        roll, pitch: (T, B) [rad]; contact: (T, B, 4) commanded stance;
        best_cost, initial_cost: (T, B); fallen: (B,) bool; qpos: (T, B, 19).
    """

    time: np.ndarray
    base_vel_w: np.ndarray
    base_height: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    contact: np.ndarray
    best_cost: np.ndarray
    initial_cost: np.ndarray
    fallen: np.ndarray
    qpos: np.ndarray


def run_baseline(
    cmd_vel_h: tuple[float, float, float] = (0.5, 0.0, 0.0),
    seconds: float = 15.0,
    num_robots: int = 1,
    cfg: BaselineConfig = BaselineConfig(),
    seed: int = 0,
    device: str = "cpu",
    model: mujoco.MjModel | None = None,
    origin_w: tuple[float, float] = (0.0, 0.0),
    backend: str = "cpu",
) -> BaselineRun:
    """Walk B robots on flat ground with the model-based baseline.

    ``model`` defaults to the scene's plane; a terrain scene (``sim.terrain.build_scene``) works
    too, with the robots spawned at ``origin_w`` (x, y) [m] on a flat patch at z = 0. ``backend``: the simulator
    (``sim/registry.py``); the controller reads its state on the CPU.
    """
    model = model if model is not None else mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    decimation = int(round(cfg.sampler.mpc_period / model.opt.timestep))
    ctrl = ModelBasedBaseline(num_robots, cfg, device, seed)
    cmd = torch.tensor(cmd_vel_h, dtype=torch.float32).expand(num_robots, 3)
    rec: dict[str, list] = {k: [] for k in ("time", "base_vel_w", "base_height", "roll", "pitch", "contact",
                                            "best_cost", "initial_cost", "qpos")}
    fallen = np.zeros(num_robots, dtype=bool)
    with make_backend(backend, model, num_robots, SimConfig(num_workers=0)) as sim:
        home = home_state(num_robots, seed, 0.0)
        home["base_pos_w"] = home["base_pos_w"] + torch.tensor([*origin_w, 0.0], dtype=torch.float64)
        state = sim.reset(torch.arange(num_robots), **home).to("cpu")
        for k in range(int(round(seconds / cfg.sampler.mpc_period))):
            result, _ = ctrl.step(state, cmd)
            sim.set_references(result.f, result.d, result.foot_target_w, result.force_w)
            state = sim.step(decimation).to("cpu")
            rpy = rpy_from_rotmat(quat_to_rotmat(state.base_quat_w.double()))
            fallen |= (state.base_contact | state.diverged).numpy()
            rec["time"].append((k + 1) * cfg.sampler.mpc_period)
            rec["base_vel_w"].append(state.base_lin_vel_w.numpy().copy())
            rec["base_height"].append(state.base_pos_w[:, 2].numpy().copy())
            rec["roll"].append(rpy[:, 0].numpy())
            rec["pitch"].append(rpy[:, 1].numpy())
            rec["contact"].append(state.contact_cmd.numpy().copy())
            rec["best_cost"].append(result.best_cost.cpu().numpy())
            rec["initial_cost"].append(result.initial_cost.cpu().numpy())
            rec["qpos"].append(torch.cat([state.base_pos_w, state.base_quat_w, state.joint_pos], 1).numpy())
    return BaselineRun(**{k: np.asarray(v) for k, v in rec.items()}, fallen=fallen)
