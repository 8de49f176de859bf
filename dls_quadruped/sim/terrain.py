"""Procedural terrains in one MuJoCo height field, and an exact batched height lookup.

Layout (IsaacLab style): a grid of square tiles, rows = difficulty (row 0 easiest, along world
x), columns = terrain type (along world y), surrounded by a flat border. The whole grid is one
``hfield`` asset centred on the world origin, added with ``mujoco.MjSpec`` to the robot scene
(the scene's ground plane is removed). Every tile has its outer edge at z = 0 so neighbouring
tiles join without cliffs, and a flat platform at its centre where robots spawn.

Tile types (the name says what a robot meets when it walks *away* from the spawn point):

- ``flat``: z = 0.
- ``rugged``: uniform random heights in [-a, a] on a coarse grid (``rugged_scale``), bilinearly
  refined onto the height-field vertices.
- ``slope_up`` / ``slope_down``: pyramid with gradient s; the centre is a pit (up) or a summit (down).
- ``boxes``: square boxes of side ``box_size`` with random heights in [-h, h].
- ``stairs_up`` / ``stairs_down``: pyramid stairs of step height h and tread ``step_width``;
  the centre platform is at the bottom (up) or at the top (down).

Difficulty parameters (a, s, h) grow linearly from the first to the last row between the
``(easiest, hardest)`` values of the config.

Height lookup: MuJoCo triangulates each height-field cell (r, c) along the diagonal from
vertex (r, c) to vertex (r + 1, c + 1) (r indexes y, c indexes x). ``Terrain.height_at`` does the
same piecewise-linear interpolation on the *compiled* model's height data (MuJoCo normalises
the elevation data to [0, 1] and scales it by ``size[2]``), so it is exact up to float32
rounding; ``tests/sim/test_terrain.py`` checks it against ``mujoco.mj_ray``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch

from dls_quadruped.robots.aliengo import constants as C

TERRAIN_TYPES: tuple[str, ...] = ("flat", "rugged", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down")
TERRAIN_GEOM_NAME = "terrain"
FLOOR_GEOM_NAME = "floor"


@dataclass(frozen=True)
class TerrainConfig:
    """Terrain generator settings (lengths in metres; ``(easiest, hardest)`` ranges per row).

    Attributes:
        types: one column per entry, each a name from ``TERRAIN_TYPES`` (repeat to weight a type).
        num_rows: number of difficulty levels.
        tile_size: side of a square tile [m].
        horizontal_scale: height-field vertex spacing [m].
        border: width of the flat frame around the tile grid [m].
        platform: side of the flat spawn platform at each tile centre [m].
        rugged_amplitude: half-range a of the uniform noise [m].
        rugged_scale: spacing of the coarse noise grid [m].
        slope: pyramid gradient s [rise / run].
        box_height: half-range h of the box heights [m].
        box_size: side of one box [m].
        step_height: stair step height [m] (thesis: 5-50 cm).
        step_width: stair tread [m].
        seed: random seed of the generator (rugged, boxes).
    """

    types: tuple[str, ...] = ("flat",)
    num_rows: int = 10
    tile_size: float = 8.0
    horizontal_scale: float = 0.05
    border: float = 3.0
    platform: float = 2.0
    rugged_amplitude: tuple[float, float] = (0.01, 0.08)
    rugged_scale: float = 0.2
    slope: tuple[float, float] = (0.0, 0.4)
    box_height: tuple[float, float] = (0.02, 0.15)
    box_size: float = 0.5
    step_height: tuple[float, float] = (0.05, 0.5)
    step_width: float = 0.3
    seed: int = 0

    def __post_init__(self) -> None:
        unknown = [t for t in self.types if t not in TERRAIN_TYPES]
        if unknown or not self.types:
            raise ValueError(f"TerrainConfig.types: unknown or empty {unknown or self.types}; allowed: {TERRAIN_TYPES}")
        if self.num_rows < 1:
            raise ValueError(f"TerrainConfig.num_rows must be >= 1, got {self.num_rows}")
        cells = self.tile_size / self.horizontal_scale
        if abs(cells - round(cells)) > 1e-6:
            raise ValueError("TerrainConfig.tile_size must be a multiple of horizontal_scale")

    @property
    def is_flat(self) -> bool:
        """True when every column is flat: the scene keeps MuJoCo's ground plane (cheaper contacts)."""
        return all(t == "flat" for t in self.types)


def _lerp(rng: tuple[float, float], difficulty: float) -> float:
    return rng[0] + difficulty * (rng[1] - rng[0])


def _tile_heights(kind: str, xl: np.ndarray, yl: np.ndarray, difficulty: float, cfg: TerrainConfig,
                  rng: np.random.Generator) -> np.ndarray:
    """Heights [m] of one tile at tile-local vertex coordinates ``xl, yl`` (centre = 0, edge = +-L/2)."""
    half = 0.5 * cfg.tile_size
    half_p = 0.5 * cfg.platform
    d = np.maximum(np.abs(xl), np.abs(yl))  # Chebyshev distance from the centre: square pyramids
    if kind == "flat":
        return np.zeros_like(xl)
    if kind == "rugged":
        a = _lerp(cfg.rugged_amplitude, difficulty)
        n = round(cfg.tile_size / cfg.rugged_scale)
        coarse = rng.uniform(-a, a, size=(n + 1, n + 1))
        coarse[[0, -1], :] = 0.0  # keep the tile edge at z = 0
        coarse[:, [0, -1]] = 0.0
        gx = (xl + half) / cfg.rugged_scale
        gy = (yl + half) / cfg.rugged_scale
        ix = np.clip(np.floor(gx).astype(int), 0, n - 1)
        iy = np.clip(np.floor(gy).astype(int), 0, n - 1)
        u, v = gx - ix, gy - iy
        return ((1 - u) * (1 - v) * coarse[iy, ix] + u * (1 - v) * coarse[iy, ix + 1]
                + (1 - u) * v * coarse[iy + 1, ix] + u * v * coarse[iy + 1, ix + 1])
    if kind in ("slope_up", "slope_down"):
        s = _lerp(cfg.slope, difficulty)
        z = s * (half - np.clip(d, half_p, half))  # summit on the platform, 0 at the edge
        return z if kind == "slope_down" else -z
    if kind == "boxes":
        h = _lerp(cfg.box_height, difficulty)
        n = int(np.ceil(cfg.tile_size / cfg.box_size))
        heights = rng.uniform(-h, h, size=(n, n))
        ix = np.clip(((xl + half) / cfg.box_size).astype(int), 0, n - 1)
        iy = np.clip(((yl + half) / cfg.box_size).astype(int), 0, n - 1)
        z = heights[iy, ix]
        z[d <= half_p] = 0.0
        z[d >= half - 1e-9] = 0.0
        return z
    if kind in ("stairs_up", "stairs_down"):
        h = _lerp(cfg.step_height, difficulty)
        num_steps = int(np.floor((half - half_p) / cfg.step_width + 1e-9))
        # step index counted from the platform (0) to the outermost tread (num_steps)
        k = np.clip(np.ceil((d - half_p) / cfg.step_width - 1e-9), 0, num_steps)
        z = (num_steps - k) * h
        return z if kind == "stairs_down" else -z
    raise ValueError(f"unknown terrain type {kind!r}; allowed: {TERRAIN_TYPES}")


def generate_heights(cfg: TerrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Build the height grid and the tile origins.

    Returns:
        heights: (ny, nx) [m] vertex heights, row index = y, column index = x (MuJoCo's hfield order).
        origins_local: (num_rows, num_cols, 2) [m] tile centres relative to the grid centre (x, y).
    """
    rng = np.random.default_rng(cfg.seed)
    hs = cfg.horizontal_scale
    n_tile = round(cfg.tile_size / hs)
    n_border = round(cfg.border / hs)
    n_rows, n_cols = cfg.num_rows, len(cfg.types)
    nx = n_rows * n_tile + 2 * n_border + 1
    ny = n_cols * n_tile + 2 * n_border + 1
    heights = np.zeros((ny, nx))
    local = (np.arange(n_tile + 1) * hs) - 0.5 * cfg.tile_size
    xl, yl = np.meshgrid(local, local, indexing="xy")  # (n_tile+1, n_tile+1), [iy, ix]
    origins = np.zeros((n_rows, n_cols, 2))
    size_x, size_y = (nx - 1) * hs, (ny - 1) * hs
    for row in range(n_rows):  # a few dozen tiles, generated once: a loop is clearer than batching
        difficulty = row / max(n_rows - 1, 1)
        for col, kind in enumerate(cfg.types):
            x0 = n_border + row * n_tile
            y0 = n_border + col * n_tile
            heights[y0:y0 + n_tile + 1, x0:x0 + n_tile + 1] = _tile_heights(kind, xl, yl, difficulty, cfg, rng)
            origins[row, col] = ((x0 + 0.5 * n_tile) * hs - 0.5 * size_x, (y0 + 0.5 * n_tile) * hs - 0.5 * size_y)
    return heights, origins


@dataclass
class Terrain:
    """The generated terrain: height grid (as compiled by MuJoCo), tile origins and lookup.

    Attributes:
        cfg: the generator settings.
        heights_w: (ny, nx) [m] world-frame vertex heights (float64 numpy, from the compiled model).
        origin_w: (2,) [m] world position of vertex (0, 0) (the grid's lower-left corner).
        spacing: (2,) [m] vertex spacing (dx, dy).
        tile_origins_w: (num_rows, num_cols, 3) [m] spawn points (tile centres on the terrain surface).
        is_plane: True when the scene keeps MuJoCo's flat ground plane at z = 0 (all-flat config).
    """

    cfg: TerrainConfig
    heights_w: np.ndarray
    origin_w: np.ndarray
    spacing: np.ndarray
    tile_origins_w: np.ndarray
    is_plane: bool
    _heights_t: dict = field(default_factory=dict, repr=False)

    @property
    def num_rows(self) -> int:
        return self.tile_origins_w.shape[0]

    @property
    def num_cols(self) -> int:
        return self.tile_origins_w.shape[1]

    def _table(self, device: torch.device) -> torch.Tensor:
        key = str(device)
        if key not in self._heights_t:
            self._heights_t[key] = torch.as_tensor(self.heights_w, dtype=torch.float32, device=device)
        return self._heights_t[key]

    def height_at(self, x_w: torch.Tensor, y_w: torch.Tensor) -> torch.Tensor:
        """Terrain height under world points, exactly as MuJoCo's triangulated height field.

        Args:
            x_w, y_w: same-shape tensors [m], world frame. Points outside the field are clamped to its edge.

        Returns:
            z_w: tensor of the same shape [m].
        """
        if self.is_plane:
            return torch.zeros_like(x_w)
        table = self._table(x_w.device)
        ny, nx = table.shape
        gx = ((x_w - float(self.origin_w[0])) / float(self.spacing[0])).clamp(0.0, nx - 1.0)
        gy = ((y_w - float(self.origin_w[1])) / float(self.spacing[1])).clamp(0.0, ny - 1.0)
        c = gx.floor().clamp(max=nx - 2).long()
        r = gy.floor().clamp(max=ny - 2).long()
        u, v = gx - c, gy - r  # cell-local coordinates in [0, 1]
        h00, h01 = table[r, c], table[r, c + 1]  # h[r, c] at (x_c, y_r); h01 is one step in x
        h10, h11 = table[r + 1, c], table[r + 1, c + 1]
        lower = u >= v  # triangle (r,c), (r,c+1), (r+1,c+1) below the diagonal
        z_lower = h00 + u * (h01 - h00) + v * (h11 - h01)
        z_upper = h00 + v * (h10 - h00) + u * (h11 - h10)
        return torch.where(lower, z_lower, z_upper)

    def height_fn(self):
        """The ``(x, y) -> z`` callable the latent-action pipeline expects."""
        return self.height_at


def build_scene(cfg: TerrainConfig, scene_path=C.SCENE_PATH) -> tuple[mujoco.MjModel, Terrain]:
    """The AlienGo scene with this terrain: load ``scene_path``, swap the floor plane for the height field.

    Returns:
        model: compiled MuJoCo model (one robot + ground).
        terrain: the matching ``Terrain`` (heights read back from the compiled model).
    """
    spec = mujoco.MjSpec.from_file(str(scene_path))
    heights, origins = generate_heights(cfg)
    hs = cfg.horizontal_scale
    ny, nx = heights.shape
    size_x, size_y = (nx - 1) * hs, (ny - 1) * hs
    if cfg.is_flat:
        model = spec.compile()
        tile_origins = np.concatenate([origins, np.zeros(origins.shape[:2] + (1,))], axis=-1)
        return model, Terrain(cfg, np.zeros((2, 2)), np.array([-0.5 * size_x, -0.5 * size_y]),
                              np.array([size_x, size_y]), tile_origins, is_plane=True)
    floor = spec.geom(FLOOR_GEOM_NAME)
    friction, material = list(floor.friction), floor.material
    contype, conaffinity = floor.contype, floor.conaffinity
    spec.delete(floor)
    z_min, z_max = float(heights.min()), float(heights.max())
    z_range = max(z_max - z_min, 1e-3)
    hfield = spec.add_hfield()
    hfield.name = TERRAIN_GEOM_NAME
    hfield.nrow, hfield.ncol = ny, nx
    hfield.size = [0.5 * size_x, 0.5 * size_y, z_range, 1.0]  # (radius x, radius y, elevation, base depth)
    hfield.userdata = ((heights - z_min) / z_range).ravel().tolist()
    geom = spec.worldbody.add_geom()
    geom.name = TERRAIN_GEOM_NAME
    geom.type = mujoco.mjtGeom.mjGEOM_HFIELD
    geom.hfieldname = TERRAIN_GEOM_NAME
    geom.pos = [0.0, 0.0, z_min]
    geom.friction = friction
    geom.material = material
    geom.contype, geom.conaffinity = contype, conaffinity
    model = spec.compile()
    hid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, TERRAIN_GEOM_NAME)
    gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TERRAIN_GEOM_NAME)
    adr = model.hfield_adr[hid]
    data = model.hfield_data[adr:adr + ny * nx].astype(np.float64).reshape(ny, nx)
    heights_w = model.geom_pos[gid, 2] + data * model.hfield_size[hid, 2]
    terrain = Terrain(cfg, heights_w, np.array([-0.5 * size_x, -0.5 * size_y]), np.array([hs, hs]),
                      np.zeros(origins.shape[:2] + (3,)), is_plane=False)
    ox = torch.as_tensor(origins[..., 0], dtype=torch.float32)
    oy = torch.as_tensor(origins[..., 1], dtype=torch.float32)
    oz = terrain.height_at(ox, oy).numpy()
    terrain.tile_origins_w = np.concatenate([origins, oz[..., None]], axis=-1)
    return model, terrain
