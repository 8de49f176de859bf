"""Scene manager: terrain + MuJoCo model + vectorised simulator, terrain levels and spawn origins.

Task file::

    terrain: {types: [flat, rugged, ...], num_rows: 10, ...}   # TerrainConfig fields
    scene: {backend: cpu, num_workers: -1, max_init_level: 0, leg_dynamics: pinocchio, nconmax: 16, njmax: 64,
           compile: null, cuda_graph: null}  # nconmax/njmax/compile/cuda_graph: Warp only

Each env owns a terrain tile: row = level (difficulty), column = type (envs spread evenly over
the columns by their episode key, ``envs/schedule.py``). Robots reset onto their tile origin; the
terrain curriculum moves rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import mujoco
import torch

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.managers.base import ManagerBase
from dls_quadruped.envs.value_checks import dataclass_from_dict
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.height_scan import HeightScanConfig, scan_pattern
from dls_quadruped.sim.interface import LEG_DYNAMICS, SimBackend, SimConfig
from dls_quadruped.sim.regions import RegionConfig
from dls_quadruped.sim.registry import backend_names, check_backend, make_backend
from dls_quadruped.sim.terrain import TerrainConfig, build_scene


@dataclass(frozen=True)
class SceneConfig:
    """backend: the simulator (``sim/registry.py``; ``cpu`` = MuJoCo's C batch + Pinocchio);
    num_workers: simulator worker processes (-1 one per core, 0 in-process);
    max_init_level: envs start on rows U{0..max_init_level};
    terrain_regions: on a tiled terrain, each robot collides only with the geoms near it
    (``sim/regions.py``: same contacts, 2-3x cheaper physics); false runs every robot on the whole terrain;
    leg_dynamics: ``cpu`` backend, where the low-level controller's leg terms come from (``SimConfig.leg_dynamics``):
    ``pinocchio`` (default) or ``mujoco`` (MuJoCo's M and bias forces of each robot's own model);
    nconmax, njmax: Warp backends, contacts and constraint rows allocated per robot (``SimConfig``; null: MuJoCo
    Warp's guess for the model); the task files set them from measured use (docs/gpu.md "Contact and constraint
    sizes");
    compile: Warp backends, the torch work of a physics step compiled into a few fused kernels (``SimConfig.compile``;
    null: on for CUDA devices, off elsewhere; ``sim/warp_control.py``);
    cuda_graph: Warp backends, each env step replayed from one captured graph (``envs/env_graph.py``; on warp-cpu
    the replay is emulated, for tests); null: off (docs/gpu.md "One graph per env step")."""

    backend: str = "cpu"
    num_workers: int = field(default=-1, metadata={"min": -1})
    max_init_level: int = field(default=0, metadata={"min": 0})
    terrain_regions: bool = True
    leg_dynamics: str = "pinocchio"
    nconmax: int | None = field(default=None, metadata={"min": 1})
    njmax: int | None = field(default=None, metadata={"min": 1})
    compile: bool | None = None
    cuda_graph: bool | None = None


class SceneManager(ManagerBase):
    def __init__(self, task: TaskConfig, env):
        super().__init__(env)
        self.cfg = dataclass_from_dict(SceneConfig, task.section("scene"), task, "scene")
        self.terrain_cfg = dataclass_from_dict(TerrainConfig, task.section("terrain"), task, "terrain")
        try:
            check_backend(self.cfg.backend)
        except ValueError:
            raise task.error("scene.backend", f"unknown simulator backend {self.cfg.backend!r}; "
                                              f"allowed: {list(backend_names())}") from None
        if self.cfg.leg_dynamics not in LEG_DYNAMICS:
            raise task.error("scene.leg_dynamics", f"unknown leg_dynamics {self.cfg.leg_dynamics!r}; "
                                                   f"allowed: {list(LEG_DYNAMICS)}")
        self.model, self.terrain = build_scene(self.terrain_cfg)
        regions = RegionConfig(self.terrain_cfg) if self.cfg.terrain_regions and not self.terrain.is_plane else None
        self.sim: SimBackend = make_backend(self.cfg.backend, self.model, env.num_envs,
                                            SimConfig(num_workers=self.cfg.num_workers, regions=regions,
                                                      leg_dynamics=self.cfg.leg_dynamics, nconmax=self.cfg.nconmax,
                                                      njmax=self.cfg.njmax, compile=self.cfg.compile))
        self.scan_cfg = HeightScanConfig()
        dev = env.device
        self.scan_pattern = scan_pattern(self.scan_cfg, dev)
        n = env.num_envs
        self.tile_origins = torch.as_tensor(self.terrain.tile_origins_w, dtype=torch.float32, device=dev)
        self.terrain_types = torch.zeros(n, dtype=torch.long, device=dev)
        self.terrain_levels = torch.zeros(n, dtype=torch.long, device=dev)
        self.env_origins = torch.zeros(n, 3, device=dev)
        self.assign_tiles()
        # foot contacts take the feet's friction (contact priority 1), so randomising the feet is enough
        self.friction_geom_ids = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES]

    def assign_tiles(self) -> None:
        """Every env's tile from the episode schedule (``env.schedule``): column = episode key mod the
        number of types (envs spread evenly over the columns), row = U{0..max_init_level} drawn from the
        key's schedule, so envs that share a key share a tile."""
        schedule, rows = self.env.schedule, self.terrain.num_rows
        ids = torch.arange(self.env.num_envs, device=self.env.device)
        self.terrain_types = schedule.keys % self.terrain.num_cols
        max_init = min(self.cfg.max_init_level, rows - 1)
        self.terrain_levels = schedule.integers(ids, 0, max_init + 1, stream="terrain_init")
        self.env_origins = self.tile_origins[self.terrain_levels, self.terrain_types].clone()

    @property
    def difficulty(self) -> torch.Tensor:
        """(B,) terrain difficulty in [0, 1] (row / (rows - 1))."""
        return self.terrain_levels.float() / max(self.terrain.num_rows - 1, 1)

    def update_levels(self, env_ids: torch.Tensor, delta: torch.Tensor) -> None:
        """Move envs by ``delta`` rows; beyond the last row -> a random row; below 0 -> 0. ``env_ids``: (n,) ids with
        ``delta`` (n,), or a (B,) bool mask with ``delta`` (B,) of every env (static shapes: the masked rows kept; the
        curriculum calls it so, inside ``schedule.only(mask)``)."""
        rows = self.terrain.num_rows
        if env_ids.dtype == torch.bool:
            ids = torch.arange(self.env.num_envs, device=self.env.device)
            lv = self.terrain_levels + delta
            lv = torch.where(lv >= rows, self.env.schedule.integers(ids, 0, rows, stream="terrain_level"),
                             lv.clamp(min=0))
            self.terrain_levels.copy_(torch.where(env_ids, lv, self.terrain_levels))
            self.env_origins.copy_(self.tile_origins[self.terrain_levels, self.terrain_types])
            return
        lv = self.terrain_levels[env_ids] + delta
        random_level = self.env.schedule.integers(env_ids, 0, rows, stream="terrain_level")
        lv = torch.where(lv >= rows, random_level, lv.clamp(min=0))
        self.terrain_levels[env_ids] = lv
        self.env_origins[env_ids] = self.tile_origins[lv, self.terrain_types[env_ids]]

    def state_dict(self) -> dict[str, Any]:
        """``{"terrain_levels": (B,) long}`` on the CPU."""
        return {"terrain_levels": self.terrain_levels.cpu().clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Move every robot to its saved level; saved for another number of robots, the saved levels are cycled
        over this env's robots (the level distribution is kept)."""
        self.check_state_dict(state)
        n, dev = self.env.num_envs, self.env.device
        levels = torch.as_tensor(state["terrain_levels"], dtype=torch.long)
        if levels.shape != (n,):
            levels = levels[torch.arange(n) % len(levels)]
        self.update_levels(torch.arange(n, device=dev), levels.to(dev) - self.terrain_levels)

    def reset_robots(self, env_ids: torch.Tensor, base_pos_w: torch.Tensor, base_quat_w: torch.Tensor,
                     joint_pos: torch.Tensor) -> None:
        self.sim.reset(env_ids, base_pos_w, base_quat_w, joint_pos)

    def close(self) -> None:
        self.sim.close()
