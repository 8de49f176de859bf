"""The terrain's MuJoCo geometry: the tiles of a draw (``sim/terrain_tiles.py``) as static geoms of an ``MjSpec``.

Why not one height field: MuJoCo collides a height field prism by prism, and a foot
sphere whose contact patch straddles a triangle edge gets several contacts with normals tilted
up to 16 deg at 1 mm penetration (36 deg at 5 mm) even on a perfectly flat field; the measured
table is in ``docs/env.md``. So every surface that is piecewise planar is built from shapes whose
faces *are* the surface: boxes for flat ground, platforms, box cells and stair treads (risers
are real box edges), convex meshes for the slope faces (a summit is one frustum; a pit is four
wedges around a platform box). Only ``rugged`` stays a height field (one per tile, one vertex per
noise sample: it is genuinely creased at every triangle edge).

A window (``sim/regions.py``) keeps only the geoms near one cell, with the whole terrain's geom names.
"""

from __future__ import annotations

import mujoco
import numpy as np

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain_tiles import TERRAIN_TYPES, TerrainConfig, TileSet

TERRAIN_GEOM_PREFIX = "terrain"
FLOOR_GEOM_NAME = "floor"
_DEPTH = 1.0  # [m] every terrain solid reaches this far below the lowest surface point


class TerrainBuilder:
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


def _add_tile(b: TerrainBuilder, name: str, p: float, cx: float, cy: float, tiles: TileSet, r: int, k: int,
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


def terrain_spec(cfg: TerrainConfig, tiles: TileSet, scene_path=C.SCENE_PATH,
                 window: tuple[float, float, float, float] | None = None) -> tuple[mujoco.MjSpec, TerrainBuilder]:
    """The scene's spec with the tiles' geoms in place of the floor plane (a tiled ``cfg``, not flat).

    ``window`` = (x0, x1, y0, y1) [m, world] keeps only the geoms whose xy extent meets that rectangle,
    in the same order as the whole terrain (``sim/regions.py``); None keeps every geom.
    """
    spec = mujoco.MjSpec.from_file(str(scene_path))
    R, K, L = cfg.num_rows, len(cfg.types), cfg.tile_size
    floor = spec.geom(FLOOR_GEOM_NAME)
    lowest = min(0.0, float(tiles.rugged.min()), float(tiles.boxes.min()),
                 -float(tiles.param.max()) * max(cfg.num_steps, 0.5 * (L - cfg.platform)))
    builder = TerrainBuilder(spec, floor, lowest - _DEPTH, window)
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
