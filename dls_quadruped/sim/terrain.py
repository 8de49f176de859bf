"""Procedural terrains built from MuJoCo primitives (``build_scene``), and an exact batched height lookup.

A terrain is a grid of square tiles drawn by ``sim/terrain_tiles.py`` (layout, tile types, difficulty) and
built as static geoms by ``sim/terrain_geometry.py`` (boxes, convex meshes, one small height field per
rugged tile). :func:`build_scene` puts them in the AlienGo scene in place of the floor plane and returns the
matching :class:`Terrain`.

Height lookup: ``Terrain.height_at`` evaluates the same closed forms per tile (and MuJoCo's own
triangulated interpolation on the compiled rugged height data), so it is exact up to float32
rounding; ``tests/sim/test_terrain.py`` checks it against ``mujoco.mj_ray`` on every type.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain_geometry import terrain_spec
from dls_quadruped.sim.terrain_tiles import (
    TERRAIN_TYPES,
    TerrainConfig,
    TileSet,
    generate_tiles,
)


@dataclass
class Terrain:
    """The generated terrain: per-tile parameters, tile origins and the exact height lookup.

    Attributes:
        cfg: the generator settings.
        tiles: what the generator drew; ``tiles.rugged`` holds the heights as compiled by MuJoCo.
        tile_origins_w: (num_rows, num_cols, 3) [m] spawn points (tile centres on the surface).
        is_plane: True when the scene keeps MuJoCo's flat ground plane at z = 0 (all-flat config).
    """

    cfg: TerrainConfig
    tiles: TileSet
    tile_origins_w: np.ndarray
    is_plane: bool
    _tables: dict = field(default_factory=dict, repr=False)

    @property
    def num_rows(self) -> int:
        return self.tile_origins_w.shape[0]

    @property
    def num_cols(self) -> int:
        return self.tile_origins_w.shape[1]

    def _t(self, device: torch.device) -> dict[str, torch.Tensor]:
        key = str(device)
        if key not in self._tables:
            t = self.tiles
            self._tables[key] = {n: torch.as_tensor(getattr(t, n), device=device)
                                 for n in ("kind", "param", "rugged", "boxes")}
            self._tables[key]["rugged"] = self._tables[key]["rugged"].float()
            self._tables[key]["boxes"] = self._tables[key]["boxes"].float()
            self._tables[key]["param"] = self._tables[key]["param"].float()
        return self._tables[key]

    def height_at(self, x_w: torch.Tensor, y_w: torch.Tensor) -> torch.Tensor:
        """Terrain height under world points, exactly as MuJoCo's geometry.

        Args:
            x_w, y_w: same-shape tensors [m], world frame. Points on the border or beyond are at z = 0.

        Returns:
            z_w: tensor of the same shape [m].
        """
        if self.is_plane:
            return torch.zeros_like(x_w)
        cfg, t = self.cfg, self._t(x_w.device)
        R, K = self.num_rows, self.num_cols
        L, half, hp = cfg.tile_size, 0.5 * cfg.tile_size, 0.5 * cfg.platform
        fr = (x_w + 0.5 * R * L) / L  # tile coordinates: row along x, column along y
        fc = (y_w + 0.5 * K * L) / L
        inside = (fr >= 0) & (fr < R) & (fc >= 0) & (fc < K)
        r = fr.floor().long().clamp(0, R - 1)
        k = fc.floor().long().clamp(0, K - 1)
        xl = (fr - r) * L - half  # tile frame [m]
        yl = (fc - k) * L - half
        kind, p = t["kind"][r, k], t["param"][r, k]
        d = torch.maximum(xl.abs(), yl.abs())  # Chebyshev distance: square pyramids
        slope = p * (half - d.clamp(hp, half))
        n = cfg.num_steps
        step = ((d - hp) / cfg.step_width - 1e-6).ceil().clamp(0, n)  # tread index from the platform out
        stairs = (n - step) * p
        nb = t["boxes"].shape[-1]
        ix = ((xl + half) / cfg.box_size).floor().long().clamp(0, nb - 1)
        iy = ((yl + half) / cfg.box_size).floor().long().clamp(0, nb - 1)
        boxes = t["boxes"][r, k, iy, ix]
        rugged = _triangulated(t["rugged"].reshape(R * K, *t["rugged"].shape[2:]), r * K + k,
                               (xl + half) / cfg.rugged_scale, (yl + half) / cfg.rugged_scale)
        z = torch.zeros_like(x_w)
        for name, value in (("rugged", rugged), ("slope_up", -slope), ("slope_down", slope), ("boxes", boxes),
                            ("stairs_up", -stairs), ("stairs_down", stairs)):
            z = torch.where(kind == TERRAIN_TYPES.index(name), value, z)
        return torch.where(inside, z, torch.zeros_like(z))

    def height_fn(self):
        """The ``(x, y) -> z`` callable the latent-action pipeline expects."""
        return self.height_at


def _triangulated(table: torch.Tensor, tile: torch.Tensor, gx: torch.Tensor, gy: torch.Tensor) -> torch.Tensor:
    """MuJoCo's height-field interpolation: cell (r, c) split along vertex (r, c) -> (r+1, c+1).

    Args:
        table: (T, G, G) vertex heights of T tiles (row = y, column = x).
        tile: (...) long, which tile each point reads.
        gx, gy: (...) grid coordinates, clamped to [0, G - 1].
    """
    G = table.shape[-1]
    flat = table.reshape(-1)
    gx, gy = gx.clamp(0.0, G - 1.0), gy.clamp(0.0, G - 1.0)
    c = gx.floor().clamp(max=G - 2).long()
    r = gy.floor().clamp(max=G - 2).long()
    u, v = gx - c, gy - r  # cell-local coordinates in [0, 1]
    base = tile * (G * G) + r * G + c
    h00, h01, h10, h11 = flat[base], flat[base + 1], flat[base + G], flat[base + G + 1]
    z_lower = h00 + u * (h01 - h00) + v * (h11 - h01)  # triangle (r,c), (r,c+1), (r+1,c+1): u >= v
    z_upper = h00 + v * (h10 - h00) + u * (h11 - h10)
    return torch.where(u >= v, z_lower, z_upper)


def build_scene(cfg: TerrainConfig, scene_path=C.SCENE_PATH) -> tuple[mujoco.MjModel, Terrain]:
    """The AlienGo scene with this terrain: load ``scene_path``, swap the floor plane for the tiles.

    Returns:
        model: compiled MuJoCo model (one robot + ground).
        terrain: the matching ``Terrain`` (rugged heights read back from the compiled model).
    """
    tiles = generate_tiles(cfg)
    R, K = cfg.num_rows, len(cfg.types)
    if cfg.is_flat:
        origins = np.concatenate([tiles.centres, np.zeros((R, K, 1))], axis=-1)
        return mujoco.MjSpec.from_file(str(scene_path)).compile(), Terrain(cfg, tiles, origins, is_plane=True)
    spec, builder = terrain_spec(cfg, tiles, scene_path)
    model = spec.compile()
    # MuJoCo stores height-field elevations as float32 fractions of the range: read back what it collides with
    for (r, k), name in builder.hfields.items():
        geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)
        hid = model.geom_dataid[geom]
        n_r, n_c, adr = model.hfield_nrow[hid], model.hfield_ncol[hid], model.hfield_adr[hid]
        data = model.hfield_data[adr:adr + n_r * n_c].astype(np.float64).reshape(n_r, n_c)
        tiles.rugged[r, k] = model.geom_pos[geom, 2] + data * model.hfield_size[hid, 2]
    terrain = Terrain(cfg, tiles, np.zeros((R, K, 3)), is_plane=False)
    ox = torch.as_tensor(tiles.centres[..., 0], dtype=torch.float32)
    oy = torch.as_tensor(tiles.centres[..., 1], dtype=torch.float32)
    oz = terrain.height_at(ox, oy).numpy()
    terrain.tile_origins_w = np.concatenate([tiles.centres, oz[..., None]], axis=-1)
    return model, terrain
