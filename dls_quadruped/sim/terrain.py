"""Procedural terrains built from MuJoCo primitives, and an exact batched height lookup.

Layout (IsaacLab style): a grid of square tiles, rows = difficulty (row 0 easiest, along world
x), columns = terrain type (along world y), surrounded by a flat border; the grid is centred on
the world origin. Every tile's outer edge is at z = 0 so neighbouring tiles join without cliffs
(``boxes`` excepted: its cells reach the edge), with a flat platform at its centre where robots
spawn.

Tile types (the name says what a robot meets when it walks *away* from the spawn point):

- ``flat``: z = 0.
- ``rugged``: uniform random heights in [-a, a] on a grid of spacing ``rugged_scale``,
  piecewise linear on MuJoCo's height-field triangulation (edge vertices at 0).
- ``slope_up`` / ``slope_down``: pyramid with gradient s; the centre is a pit (up) or a summit (down).
- ``boxes``: square boxes of side ``box_size`` with random heights in [-h, h] (platform cells at 0).
- ``stairs_up`` / ``stairs_down``: pyramid stairs of step height h and tread ``step_width``;
  the centre platform is at the bottom (up) or at the top (down).

Difficulty parameters (a, s, h) grow linearly from the first to the last row between the
``(easiest, hardest)`` values of the config.

Geometry (why not one height field): MuJoCo collides a height field prism by prism, and a foot
sphere whose contact patch straddles a triangle edge gets several contacts with normals tilted
up to 16 deg at 1 mm penetration (36 deg at 5 mm) even on a perfectly flat field; the measured
table is in ``docs/env.md``. So every surface that is piecewise planar is built from shapes whose
faces *are* the surface: boxes for flat ground, platforms, box cells and stair treads (risers
are real box edges), convex meshes for the slope faces (a summit is one frustum; a pit is four
wedges around a platform box). Only ``rugged`` stays a height field (one per tile, one vertex per
noise sample: it is genuinely creased at every triangle edge).

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

TERRAIN_TYPES: tuple[str, ...] = ("flat", "rugged", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down")
TERRAIN_GEOM_PREFIX = "terrain"
FLOOR_GEOM_NAME = "floor"
_DEPTH = 1.0  # [m] every terrain solid reaches this far below the lowest surface point


@dataclass(frozen=True)
class TerrainConfig:
    """Terrain generator settings (lengths in metres; ``(easiest, hardest)`` ranges per row).

    Attributes:
        types: one column per entry, each a name from ``TERRAIN_TYPES`` (repeat to weight a type).
        num_rows: number of difficulty levels.
        tile_size: side of a square tile [m].
        border: width of the flat frame around the tile grid [m].
        platform: side of the flat spawn platform at each tile centre [m].
        rugged_amplitude: half-range a of the uniform noise [m].
        rugged_scale: spacing of the noise samples = the rugged height field's cell [m].
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
        for name in ("tile_size", "rugged_scale", "box_size", "step_width"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TerrainConfig.{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.platform < self.tile_size:
            raise ValueError(f"TerrainConfig.platform must be in (0, tile_size={self.tile_size}), got {self.platform}")
        for name, size in (("rugged_scale", self.rugged_scale), ("box_size", self.box_size)):
            cells = self.tile_size / size
            if abs(cells - round(cells)) > 1e-6:
                raise ValueError(f"TerrainConfig.tile_size ({self.tile_size}) must be a multiple of {name} ({size})")

    @property
    def is_flat(self) -> bool:
        """True when every column is flat: the scene keeps MuJoCo's ground plane."""
        return all(t == "flat" for t in self.types)

    @property
    def num_steps(self) -> int:
        """Stair steps from the platform to the tile edge."""
        return int(np.floor((0.5 * (self.tile_size - self.platform)) / self.step_width + 1e-9))


def _lerp(rng: tuple[float, float], difficulty: float) -> float:
    return rng[0] + difficulty * (rng[1] - rng[0])


@dataclass
class TileSet:
    """What the generator drew, per tile (R rows x K columns), before any geometry exists.

    Attributes:
        kind: (R, K) int, index into ``TERRAIN_TYPES``.
        param: (R, K) [m or rise/run] the tile's a (rugged), s (slopes), h (stairs); 0 otherwise.
        rugged: (R, K, G, G) [m] rugged vertex heights on the ``rugged_scale`` grid (row = y, col = x).
        boxes: (R, K, n, n) [m] box-cell heights (row = y, col = x).
        centres: (R, K, 2) [m] tile centres, world x, y.
    """

    kind: np.ndarray
    param: np.ndarray
    rugged: np.ndarray
    boxes: np.ndarray
    centres: np.ndarray


def generate_tiles(cfg: TerrainConfig) -> TileSet:
    """Draw every tile's parameters (rugged noise, box heights) from ``cfg.seed``."""
    rng = np.random.default_rng(cfg.seed)
    R, K, L = cfg.num_rows, len(cfg.types), cfg.tile_size
    g = round(L / cfg.rugged_scale) + 1
    nb = round(L / cfg.box_size)
    kind = np.zeros((R, K), dtype=np.int64)
    param = np.zeros((R, K))
    rugged = np.zeros((R, K, g, g))
    boxes = np.zeros((R, K, nb, nb))
    centres = np.zeros((R, K, 2))
    cell_c = (np.arange(nb) + 0.5) * cfg.box_size - 0.5 * L  # box-cell centres, tile frame
    on_platform = np.maximum(np.abs(cell_c)[:, None], np.abs(cell_c)[None, :]) < 0.5 * cfg.platform
    for r in range(R):  # a few dozen tiles, drawn once: a loop is clearer than batching
        difficulty = r / max(R - 1, 1)
        for k, name in enumerate(cfg.types):
            kind[r, k] = TERRAIN_TYPES.index(name)
            centres[r, k] = ((r + 0.5) * L - 0.5 * R * L, (k + 0.5) * L - 0.5 * K * L)
            if name == "rugged":
                a = _lerp(cfg.rugged_amplitude, difficulty)
                param[r, k] = a
                z = rng.uniform(-a, a, size=(g, g))
                z[[0, -1], :] = 0.0  # the tile edge at z = 0
                z[:, [0, -1]] = 0.0
                rugged[r, k] = z
            elif name in ("slope_up", "slope_down"):
                param[r, k] = _lerp(cfg.slope, difficulty)
            elif name == "boxes":
                h = _lerp(cfg.box_height, difficulty)
                param[r, k] = h
                boxes[r, k] = np.where(on_platform, 0.0, rng.uniform(-h, h, size=(nb, nb)))
            elif name in ("stairs_up", "stairs_down"):
                param[r, k] = _lerp(cfg.step_height, difficulty)
    return TileSet(kind, param, rugged, boxes, centres)


# ------------------------------------------------------------------------------------------------
# geometry


class _Builder:
    """Adds static terrain geoms to an ``MjSpec`` world body (names ``terrain/<i>``)."""

    def __init__(self, spec: mujoco.MjSpec, floor: mujoco.MjsGeom, bottom: float,
                 window: tuple[float, float, float, float] | None = None):
        self.spec, self.bottom, self.window = spec, bottom, window
        self.count, self.index, self.num_meshes = 0, 0, 0  # geoms added, geoms asked for, meshes added
        self.hfields: dict[tuple[int, int], str] = {}  # (row, column) -> geom name of a rugged tile
        self.friction, self.material = list(floor.friction), floor.material
        self.contype, self.conaffinity = floor.contype, floor.conaffinity

    def skips(self, x0: float, x1: float, y0: float, y1: float) -> bool:
        """True when the xy rectangle [x0, x1] x [y0, y1] (world) misses the window: its geom is left out
        (asked once per geom, which keeps its whole-terrain name ``terrain/<index>`` in every window)."""
        if self.window is None:
            return False
        wx0, wx1, wy0, wy1 = self.window
        out = x1 < wx0 or x0 > wx1 or y1 < wy0 or y0 > wy1
        self.index += out
        return out

    def _geom(self, gtype: mujoco.mjtGeom) -> mujoco.MjsGeom:
        geom = self.spec.worldbody.add_geom()
        geom.name = f"{TERRAIN_GEOM_PREFIX}/{self.index}"
        self.count += 1
        self.index += 1
        geom.type = gtype
        geom.friction, geom.material = self.friction, self.material
        geom.contype, geom.conaffinity = self.contype, self.conaffinity
        return geom

    def box(self, x0: float, x1: float, y0: float, y1: float, top: float) -> None:
        """Axis-aligned box over [x0, x1] x [y0, y1] (world) whose top face is at z = ``top``."""
        if self.skips(x0, x1, y0, y1):
            return
        geom = self._geom(mujoco.mjtGeom.mjGEOM_BOX)
        geom.size = [0.5 * (x1 - x0), 0.5 * (y1 - y0), 0.5 * (top - self.bottom)]
        geom.pos = [0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (top + self.bottom)]

    def solid(self, top_xyz: np.ndarray) -> None:
        """Convex mesh: the polygon ``top_xyz`` (P, 3) [m, world] extruded straight down to the bottom."""
        bottom = top_xyz.copy()
        bottom[:, 2] = self.bottom
        mesh = self.spec.add_mesh()
        mesh.name = f"{TERRAIN_GEOM_PREFIX}/mesh{self.num_meshes}"
        self.num_meshes += 1
        mesh.uservert = np.concatenate([top_xyz, bottom]).ravel().tolist()
        # the mesh stays even when its geom is left out: every window's model then has the same
        # meshes, hence the same bounding-volume trees (MjData's layout, sim/regions.py)
        if self.skips(top_xyz[:, 0].min(), top_xyz[:, 0].max(), top_xyz[:, 1].min(), top_xyz[:, 1].max()):
            return
        geom = self._geom(mujoco.mjtGeom.mjGEOM_MESH)
        geom.meshname = mesh.name

    def hfield(self, cx: float, cy: float, half: float, heights: np.ndarray) -> str | None:
        """Height field over the square of side 2 ``half`` centred at (cx, cy); ``heights`` (G, G), row = y.
        Returns its geom's name (None when outside the window)."""
        if self.skips(cx - half, cx + half, cy - half, cy + half):
            return None
        z_min, z_max = float(heights.min()), float(heights.max())
        z_range = max(z_max - z_min, 1e-3)
        hf = self.spec.add_hfield()
        hf.name = f"{TERRAIN_GEOM_PREFIX}/hfield{self.count}"
        hf.nrow, hf.ncol = heights.shape
        hf.size = [half, half, z_range, z_min - self.bottom]  # (radius x, radius y, elevation, base depth)
        hf.userdata = ((heights - z_min) / z_range).ravel().tolist()
        geom = self._geom(mujoco.mjtGeom.mjGEOM_HFIELD)
        geom.hfieldname = hf.name
        geom.pos = [cx, cy, z_min]
        return geom.name


def _square_ring(e_in: float, half: float) -> list[tuple[float, float, float, float]]:
    """Four non-overlapping rectangles covering e_in < max(|x|, |y|) <= half (tile frame)."""
    return [(e_in, half, -half, half), (-half, -e_in, -half, half),  # east, west: full height in y
            (-e_in, e_in, e_in, half), (-e_in, e_in, -half, -e_in)]  # north, south: between them


def _add_tile(b: _Builder, name: str, p: float, cx: float, cy: float, tiles: TileSet, r: int, k: int,
              cfg: TerrainConfig) -> None:
    """The geoms of one tile; surfaces as documented in the module docstring."""
    half, hp, w = 0.5 * cfg.tile_size, 0.5 * cfg.platform, cfg.step_width

    def box(x0, x1, y0, y1, top):
        b.box(cx + x0, cx + x1, cy + y0, cy + y1, top)

    if name == "flat":
        return  # flat columns are one box each, with the border at their ends (build_scene): no seams
    if name in ("slope_up", "slope_down") and p == 0.0:
        box(-half, half, -half, half, 0.0)  # a zero slope is flat: one box, not five coplanar pieces
    elif name == "rugged":
        if (geom_name := b.hfield(cx, cy, half, tiles.rugged[r, k])) is not None:
            b.hfields[r, k] = geom_name
    elif name == "slope_down":  # one frustum: platform on top, faces down to z = 0 at the edge
        top = p * (half - hp)
        corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float)
        pts = np.concatenate([np.c_[hp * corners, np.full(4, top)], np.c_[half * corners, np.zeros(4)]])
        pts[:, 0] += cx
        pts[:, 1] += cy
        b.solid(pts)
    elif name == "slope_up":  # platform box at the bottom + four wedges (surface = max of the face planes)
        bottom_z = -p * (half - hp)
        box(-hp, hp, -hp, hp, bottom_z)
        for rot in range(4):  # the east wedge x in [hp, half], |y| <= x, rotated by rot * 90 deg
            c, s = np.cos(rot * np.pi / 2), np.sin(rot * np.pi / 2)
            local = np.array([[hp, -hp, bottom_z], [half, -half, 0.0], [half, half, 0.0], [hp, hp, bottom_z]])
            pts = local.copy()
            pts[:, 0] = cx + c * local[:, 0] - s * local[:, 1]
            pts[:, 1] = cy + s * local[:, 0] + c * local[:, 1]
            b.solid(pts)
    elif name == "boxes":
        nb = tiles.boxes.shape[-1]
        edges = np.arange(nb + 1) * cfg.box_size - half
        centre = np.abs(0.5 * (edges[:-1] + edges[1:]))
        on_platform = np.maximum(centre[:, None], centre[None, :]) < hp  # the zero cells, as in generate_tiles
        rows, cols = np.nonzero(on_platform)
        if rows.size:  # one box for the spawn platform: coplanar cells would meet at seams under the robot
            box(edges[cols.min()], edges[cols.max() + 1], edges[rows.min()], edges[rows.max() + 1], 0.0)
        for iy in range(nb):
            for ix in range(nb):
                if not on_platform[iy, ix]:
                    box(edges[ix], edges[ix + 1], edges[iy], edges[iy + 1], float(tiles.boxes[r, k, iy, ix]))
    elif name == "stairs_down":  # nested boxes, one per tread, the highest (smallest) on top
        n = cfg.num_steps
        box(-half, half, -half, half, 0.0)
        for j in range(n):
            e = hp + j * w
            box(-e, e, -e, e, (n - j) * p)
    elif name == "stairs_up":  # the platform level under the whole tile, then one square ring per step
        n = cfg.num_steps
        box(-half, half, -half, half, -n * p)
        for j in range(1, n + 1):
            for x0, x1, y0, y1 in _square_ring(hp + (j - 1) * w, half):
                box(x0, x1, y0, y1, -(n - j) * p)
    else:
        raise ValueError(f"unknown terrain type {name!r}; allowed: {TERRAIN_TYPES}")


# ------------------------------------------------------------------------------------------------
# lookup


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


def terrain_spec(cfg: TerrainConfig, tiles: TileSet, scene_path=C.SCENE_PATH,
                 window: tuple[float, float, float, float] | None = None) -> tuple[mujoco.MjSpec, _Builder]:
    """The scene's spec with the tiles' geoms in place of the floor plane (a tiled ``cfg``, not flat).

    ``window`` = (x0, x1, y0, y1) [m, world] keeps only the geoms whose xy extent meets that rectangle,
    in the same order as the whole terrain (``sim/regions.py``); None keeps every geom.
    """
    spec = mujoco.MjSpec.from_file(str(scene_path))
    R, K, L = cfg.num_rows, len(cfg.types), cfg.tile_size
    floor = spec.geom(FLOOR_GEOM_NAME)
    lowest = min(0.0, float(tiles.rugged.min()), float(tiles.boxes.min()),
                 -float(tiles.param.max()) * max(cfg.num_steps, 0.5 * (L - cfg.platform)))
    builder = _Builder(spec, floor, lowest - _DEPTH, window)
    spec.delete(floor)
    for r in range(R):
        for k, name in enumerate(cfg.types):
            cx, cy = tiles.centres[r, k]
            _add_tile(builder, name, float(tiles.param[r, k]), float(cx), float(cy), tiles, r, k, cfg)
    gx, gy, bw = 0.5 * R * L, 0.5 * K * L, cfg.border
    # the flat frame and the flat columns at z = 0, merged into as few boxes as possible: two coplanar
    # boxes meet at a seam where a foot within ~1 cm of it also touches the other box's edge (a
    # second, tilted contact; docs/env.md "Contacts"). A flat column runs through the border at its
    # ends; the border's x-end strips cover the runs of other columns between.
    builder.box(-gx - bw, gx + bw, gy, gy + bw, 0.0)
    builder.box(-gx - bw, gx + bw, -gy - bw, -gy, 0.0)
    flat = [name == "flat" for name in cfg.types]
    k = 0
    while k < K:
        k_end = k
        while k_end + 1 < K and flat[k_end + 1] == flat[k]:
            k_end += 1
        y0, y1 = k * L - gy, (k_end + 1) * L - gy
        if flat[k]:
            builder.box(-gx - bw, gx + bw, y0, y1, 0.0)
        else:
            builder.box(gx, gx + bw, y0, y1, 0.0)
            builder.box(-gx - bw, -gx, y0, y1, 0.0)
        k = k_end + 1
    return spec, builder


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

