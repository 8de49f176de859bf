"""Per-robot terrain regions: each robot collides only with the terrain geoms near it.

Why: with the whole tiled terrain in one model (~3 000 static geoms for the rough task) every
``mj_step`` recomputes the world pose of every geom (MuJoCo's kinematics has no static-geom
shortcut) and runs its mid phase over the world body's tree of all of them, so a foot contact
costs 4-6x one on a plane (``docs/benchmarks.md`` "Terrain physics cost"). Here the terrain is cut
into square cells of side ``cell`` on the tile grid; cell c's *region model* holds the robot and
every terrain geom whose xy extent meets c grown by ``margin`` on each side, in the whole
terrain's order, padded with collision-free dummies to one geom count so that every region model
gives ``MjData`` the same layout (``mujoco.batch.Batch.set_models``). A shard runs robot i on a
copy of the region model of the cell its base is in, and re-checks the cell before every physics
step (:meth:`RegionModels.cells`), so the geometry within ``margin`` of the base is always
complete: a robot whose every geom stays within ``margin - v dt`` of its base horizontally
collides with exactly the geoms it would meet in the whole terrain (``ROBOT_REACH`` and
``tests/sim/test_regions.py``).

Geom ids: terrain geoms belong to the world body, which comes first, so a region model's robot
geoms sit at ``id - num_terrain_full + num_terrain_region`` (:meth:`RegionModels.robot_geom_ids`);
body, joint, sensor and actuator ids are the whole model's.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain_geometry import terrain_spec
from dls_quadruped.sim.terrain_tiles import TerrainConfig, generate_tiles

ROBOT_REACH = 0.8
"""[m] bound on the horizontal distance from the base to any point of the robot's collision geoms
(bounding spheres of the trunk and legs: 0.75 m at worst over random joint angles and tilts, the test; a
margin of 1 m leaves 0.1 m of travel per physics step beyond ``HYSTERESIS``, 20 m/s, before a geom
could be missed)."""


HYSTERESIS = 0.1
"""[m] how far beyond its cell's edge a robot's base goes before it changes model."""

DUMMY_CONTYPE = 1 << 30
"""Collision bit of the padding geoms; no robot geom may have it in its conaffinity."""


@dataclass(frozen=True)
class RegionGrid:
    """Square cells of side ``cell`` [m] covering [x0, x0 + nx cell] x [y0, y0 + ny cell] (world)."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int
    margin: float

    @staticmethod
    def for_terrain(cfg: TerrainConfig, cell: float, margin: float) -> RegionGrid:
        """Cells over the tiles and the flat border, each tile centre at a cell centre: robots spawn
        there, and a spawn point on a cell corner would switch models at every wobble."""
        L, bw = cfg.tile_size, cfg.border

        def axis(tiles: int) -> tuple[float, int]:
            g = 0.5 * tiles * L
            first = -g + 0.5 * L - 0.5 * cell  # the cell centred on the first tile
            k = int(np.ceil((first + g + bw) / cell - 1e-9))  # cells before it, down to the border's edge
            x0 = first - k * cell
            return x0, int(np.ceil((g + bw - x0) / cell - 1e-9))

        (x0, nx), (y0, ny) = axis(cfg.num_rows), axis(len(cfg.types))
        return RegionGrid(x0, y0, cell, nx, ny, margin)

    @property
    def num_cells(self) -> int:
        return self.nx * self.ny

    def inside(self, c: np.ndarray, x_w: np.ndarray, y_w: np.ndarray, grow: float) -> np.ndarray:
        """(n,) bool: point i lies in cell c[i] grown by ``grow`` [m] (outer cells reach to infinity)."""
        ix, iy = np.divmod(c, self.ny)
        lo_x, lo_y = self.x0 + ix * self.cell - grow, self.y0 + iy * self.cell - grow
        in_x = ((ix == 0) | (x_w >= lo_x)) & ((ix == self.nx - 1) | (x_w <= lo_x + self.cell + 2 * grow))
        in_y = ((iy == 0) | (y_w >= lo_y)) & ((iy == self.ny - 1) | (y_w <= lo_y + self.cell + 2 * grow))
        return in_x & in_y

    def cells(self, x_w: np.ndarray, y_w: np.ndarray) -> np.ndarray:
        """(n,) int cell of each point (row-major, x major); points beyond the grid take the nearest
        border cell (there is no terrain beyond it, so its region holds all there is)."""
        ix = np.clip(np.floor((x_w - self.x0) / self.cell), 0, self.nx - 1).astype(np.int64)
        iy = np.clip(np.floor((y_w - self.y0) / self.cell), 0, self.ny - 1).astype(np.int64)
        return ix * self.ny + iy

    def window(self, c: int) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1) [m, world] of cell ``c`` grown by ``margin``; the outer cells reach to infinity."""
        ix, iy = divmod(c, self.ny)
        x0, y0 = self.x0 + ix * self.cell - self.margin, self.y0 + iy * self.cell - self.margin
        x1, y1 = x0 + self.cell + 2 * self.margin, y0 + self.cell + 2 * self.margin
        inf = np.inf
        return (-inf if ix == 0 else x0, inf if ix == self.nx - 1 else x1,
                -inf if iy == 0 else y0, inf if iy == self.ny - 1 else y1)


@dataclass
class RegionModels:
    """One compiled model per cell of ``grid`` (same ``MjData`` layout), and the geom-id map.

    Attributes:
        grid: the cells.
        models: ``grid.num_cells`` region models.
        num_terrain: terrain (world-body) geoms per region model, dummies included.
        num_terrain_full: world-body geoms of the whole-terrain model.
        max_geoms: most real terrain geoms in one region (the rest of ``num_terrain`` are dummies).
    """

    grid: RegionGrid
    models: list[mujoco.MjModel]
    num_terrain: int
    num_terrain_full: int
    max_geoms: int

    def robot_geom_ids(self, full_ids: np.ndarray) -> np.ndarray:
        """Region-model ids of robot geoms given by their whole-model ids.

        Raises:
            ValueError: a terrain geom (no fixed id across regions).
        """
        full_ids = np.asarray(full_ids, dtype=np.int64)
        if (full_ids < self.num_terrain_full).any():
            raise ValueError(f"geoms {full_ids[full_ids < self.num_terrain_full].tolist()} are terrain geoms, "
                             "which have no fixed id in a region model; only the robot's geoms can be set per robot")
        return full_ids - self.num_terrain_full + self.num_terrain


def build_region_models(cfg: TerrainConfig, full: mujoco.MjModel, cell: float | None = None,
                        margin: float = 1.0, scene_path=C.SCENE_PATH) -> RegionModels:
    """Compile the region model of every cell of the tiled terrain ``cfg`` (not flat).

    Args:
        cfg: the terrain (the same config that built ``full``; the tiles are redrawn from its seed).
        full: the whole-terrain model (``build_scene``), for its geom count.
        cell: cell side [m] (default: half a tile).
        margin: [m] geometry kept around a cell; must exceed ``ROBOT_REACH`` plus the travel in one
            physics step.
    """
    if cfg.is_flat:
        raise ValueError("a flat terrain is MuJoCo's plane: it has no regions")
    if margin <= ROBOT_REACH + HYSTERESIS:
        raise ValueError(f"margin {margin} m must exceed the robot's reach ROBOT_REACH + HYSTERESIS = "
                         f"{ROBOT_REACH + HYSTERESIS} m")
    if ((full.geom_conaffinity | full.geom_contype) & DUMMY_CONTYPE).any():
        raise ValueError(f"collision bit {DUMMY_CONTYPE} is the region dummies'; no geom of the scene may use it")
    grid = RegionGrid.for_terrain(cfg, 0.5 * cfg.tile_size if cell is None else cell, margin)
    tiles = generate_tiles(cfg)  # undisturbed heights: build_scene overwrites its own with the compiled ones
    specs = [terrain_spec(cfg, tiles, scene_path, grid.window(c)) for c in range(grid.num_cells)]
    counts = [b.count for _, b in specs]
    num_terrain = max(counts) + 1  # + 1: every region keeps at least one dummy, so all trees have the same shape
    for (spec, _), count in zip(specs, counts):
        for j in range(num_terrain - count):
            dummy = spec.worldbody.add_geom()
            dummy.name = f"region_dummy/{j}"
            dummy.type = mujoco.mjtGeom.mjGEOM_SPHERE
            dummy.size = [1e-3, 0, 0]
            dummy.pos = [0.0, 0.0, -1.0e3]  # far below: the broad/mid phase never reaches it
            # in the world body's tree (a geom that can collide, so every region's tree has one shape)
            # but colliding with nothing: no robot geom has this conaffinity bit
            dummy.contype, dummy.conaffinity, dummy.group = DUMMY_CONTYPE, 0, 5
    models = [spec.compile() for spec, _ in specs]
    num_full = int((full.geom_bodyid == 0).sum())
    return RegionModels(grid, models, num_terrain, num_full, max(counts))


@dataclass(frozen=True)
class RegionConfig:
    """Per-robot terrain regions for the backend (``SimConfig.regions``; built in every shard).

    Attributes:
        terrain: the tiled terrain of the backend's model (``build_scene(terrain)``).
        cell: cell side [m]; None = half a tile.
        margin: geometry kept around a cell [m] (> ``ROBOT_REACH``).
    """

    terrain: TerrainConfig
    cell: float | None = None
    margin: float = 1.0

    def build(self, full: mujoco.MjModel) -> RegionModels:
        return build_region_models(self.terrain, full, self.cell, self.margin)


class RobotRegions:
    """The model each robot of a shard runs on: its cell's region model, or a private copy of it when
    the robot has per-robot values (randomisation), re-applied whenever it changes cell.

    Args:
        regions: the region models.
        full: the whole-terrain model (the id space of :meth:`set_field`'s geom indices).
        n: robots in the shard.
    """

    def __init__(self, regions: RegionModels, full: mujoco.MjModel, n: int):
        self.regions, self.full, self.n = regions, full, n
        self.cell = np.full(n, -1, dtype=np.int64)
        self.models: list[mujoco.MjModel] = [regions.models[0]] * n
        self.custom = np.zeros(n, dtype=bool)
        self._copied_from: list[mujoco.MjModel | None] = [None] * n  # the template of robot i's private copy
        self.fields: dict[str, tuple[np.ndarray | None, np.ndarray]] = {}  # name -> (rows, (n, ...) values)

    def _model(self, i: int) -> mujoco.MjModel:
        """Robot i's model: its cell's template, or (per-robot values) a private copy of it with those values
        written in. A private copy already made from the same template is rewritten in place: copying a
        region model (every mesh included) costs ~1 ms, and a reset that redraws a robot's friction and mass
        would otherwise copy it again."""
        template = self.regions.models[self.cell[i]]
        if not self.custom[i]:
            return template
        m = self.models[i]
        if m is template or self._copied_from[i] is not template:
            m = copy.copy(template)
            self._copied_from[i] = template
        for name, (rows, values) in self.fields.items():
            field = getattr(m, name)
            if rows is None:
                field[:] = values[i]
            else:
                field[rows] = values[i]
        return m

    def update(self, x_w: np.ndarray, y_w: np.ndarray) -> bool:
        """Give every robot the model of the cell its base (x_w, y_w) (n,) [m] is in; True if any changed
        (the caller then passes :attr:`models` to ``Batch.set_models``)."""
        grid = self.regions.grid
        cells = grid.cells(x_w, y_w)
        # hysteresis: a robot keeps its model until it is HYSTERESIS beyond its cell's edge (no switching
        # back and forth while it stands on an edge); ROBOT_REACH + HYSTERESIS < margin keeps it exact
        stay = (self.cell >= 0) & grid.inside(np.maximum(self.cell, 0), x_w, y_w, HYSTERESIS)
        moved = np.flatnonzero((cells != self.cell) & ~stay)
        self.cell[moved] = cells[moved]
        for i in moved:  # robots that crossed into another cell: a few per RL step
            self.models[i] = self._model(i)
        return len(moved) > 0

    def set_field(self, name: str, ids: np.ndarray, index: np.ndarray | None, values: np.ndarray) -> None:
        """Per-robot values of a model field, as ``Batch.expand`` would write them; geom rows are given by
        their whole-model ids (robot geoms only). The models of ``ids`` are rebuilt: pass :attr:`models`
        to ``Batch.set_models`` afterwards.

        Raises:
            ValueError: terrain geoms, or a field whose layout differs between the whole and the region models.
        """
        template = self.regions.models[0]
        nrow = self.full.ngeom
        if name.startswith("geom_"):
            if index is None:  # whole-field values: keep the robot's rows
                index = np.arange(self.regions.num_terrain_full, nrow)
                values = values[:, index]
            index = self.regions.robot_geom_ids(index)
        elif getattr(template, name).shape != getattr(self.full, name).shape:
            raise ValueError(f"model field {name!r} has another layout in the region models; "
                             "per-robot values are supported for geom_* (robot geoms) and robot-sized fields")
        if name not in self.fields:
            nominal = getattr(template, name) if index is None else getattr(template, name)[index]
            self.fields[name] = (None if index is None else index, np.repeat(nominal[None].copy(), self.n, axis=0))
        rows, stored = self.fields[name]
        if (rows is None) != (index is None) or (rows is not None and not np.array_equal(rows, index)):
            raise ValueError(f"model field {name!r} was first set for rows {rows} and now for {index}; "
                             "with terrain regions a field is set for one set of rows")
        stored[ids] = values
        self.custom[ids] = True
        for i in ids:  # one model copy per robot: MuJoCo has no per-world field on a caller's model
            self.models[i] = self._model(i)

    def field(self, name: str) -> np.ndarray:
        """(n, ...) every robot's values of a model field in the whole model's layout (terrain geom rows:
        the whole model's), as ``Batch.expanded`` gives them without regions."""
        out = np.repeat(getattr(self.full, name)[None].copy(), self.n, axis=0)
        if name.startswith("geom_"):
            rows = np.arange(self.regions.num_terrain_full, self.full.ngeom)
            out[:, rows] = np.stack([getattr(m, name)[self.regions.robot_geom_ids(rows)] for m in self.models])
        else:
            out[:] = np.stack([getattr(m, name) for m in self.models])
        return out
