"""Terrain culling and collision statistics for the MuJoCo Warp backend (``sim/warp_backend.py``).

Why: MuJoCo Warp 4.0 offers two broadphases and neither fits a large static terrain. The all-pairs one
(``NXN``, its choice below 250 000 pairs) tests every robot geom against every terrain geom in every world:
39 079 pairs per world on the rough task's ~3 000 terrain geoms. Sweep-and-prune (``SAP_*``) sorts all geoms
of a world along one fixed axis and tests every overlapping interval, terrain against terrain included: about
960 000 per world on the same terrain (tiles several metres wide overlap hundreds of others on any axis).
Merging terrain geoms changes the contacts (``sim/terrain.py`` explains why the terrain is boxes and convex
meshes, not one height field). So the terrain is culled as the ``cpu`` backend's regions do (``sim/regions.py``),
without a model per cell: the terrain's xy extent is cut into square cells, each cell keeps the ids of the
terrain geoms that meet it grown by ``margin``, and each world tests its robot's geoms only against the cell its
base is in at the current step (no hysteresis: the cell is looked up at the positions the narrowphase uses).

How it plugs in: MuJoCo Warp's own broadphase keeps the pairs that do not involve a static geom (the robot's
self-collision pairs, explicit ``<pair>``s, collision-sensor pairs); the robot-terrain pairs are emitted by
:class:`TerrainCulling`'s kernel from ``Model.callback.contactfilter``, the one hook MuJoCo Warp calls inside
``step1``/``forward`` between its collision pass and the constraint build. It applies MuJoCo Warp's broadphase
filter (``Option.broadphase_filter``) to each pair and runs MuJoCo Warp's narrowphase on them, appending to the
same contact buffer, as MuJoCo Warp's own second (sleeping) collision pass does. The contacts are therefore those
of the all-pairs broadphase, possibly in another order: a robot geom reaches at most ``ROBOT_REACH`` from its
base horizontally, so a terrain geom outside the grown cell cannot touch it.

MuJoCo Warp's collision internals (``_narrowphase``, ``_broadphase_filter``, ``_add_geom_pair``) are private:
``setup.py`` pins ``mujoco-warp==4.0.0``, and ``tests/sim/test_warp_collision.py`` checks the culled contacts
against the all-pairs ones on every tile type.
"""

from __future__ import annotations

import functools

import mujoco
import mujoco_warp as mjw
import numpy as np
import torch
import warp as wp
from mujoco_warp._src.collision_core import CollisionContext
from mujoco_warp._src.collision_driver import (
    _add_geom_pair,
    _broadphase_filter,
    _narrowphase,
)
from mujoco_warp._src.math import upper_tri_index

from dls_quadruped.sim.regions import ROBOT_REACH, RegionGrid

CELL = 1.0
"""[m] default cell side: a cell is one row of geom ids (no compiled model as on ``cpu``), so cells can be small;
on the rough task 1 m cells with a 1 m margin hold at most 88 terrain geoms (<= 1 210 pair tests per world)."""

OBB_SLACK = 0.05
"""[m] how far a robot geom's oriented box reaches beyond its bounding sphere (a foot sphere's box corner: 0.02 m);
``margin`` must exceed ``ROBOT_REACH + OBB_SLACK`` plus the geoms' contact margins."""

ALLOCATION_OVERFLOWS = int(mjw.OverflowType.NEFC | mjw.OverflowType.NJMAX_NNZ | mjw.OverflowType.BROADPHASE
                           | mjw.OverflowType.NARROWPHASE | mjw.OverflowType.CCD | mjw.OverflowType.HFIELD
                           | mjw.OverflowType.EPA_HORIZON)
"""Bits of MuJoCo Warp's per-world ``Data.overflow`` that mean dropped contacts, contact candidates or constraint
rows (the solver's iteration-limit bits are not allocation problems). The contact buffer is shared by all worlds:
when it overflows MuJoCo Warp sets the contact bits of every world, since the dropped contacts may be anyone's."""


@functools.cache
def _culled_broadphase(opt_filter: int, ngeom_aabb: int, ngeom_rbound: int, ngeom_margin: int, ngeom_gap: int,
                       npair_margin: int, npair_gap: int):
    """The culling kernel for one set of MuJoCo Warp's compile-time sizes (batched model fields change them)."""
    pair_filter = _broadphase_filter(opt_filter, ngeom_aabb, ngeom_rbound, ngeom_margin, ngeom_gap, npair_margin,
                                     npair_gap)

    @wp.kernel(module="unique", enable_backward=False)
    def kernel(
        ngeom: int,
        geom_type: wp.array[int],
        geom_aabb: wp.array3d[wp.vec3],
        geom_rbound: wp.array2d[float],
        geom_margin: wp.array2d[float],
        geom_gap: wp.array2d[float],
        pair_margin: wp.array2d[float],
        pair_gap: wp.array2d[float],
        nxn_pairid: wp.array[wp.vec2i],
        xpos_in: wp.array2d[wp.vec3],
        geom_xpos_in: wp.array2d[wp.vec3],
        geom_xmat_in: wp.array2d[wp.mat33],
        naconmax_in: int,
        base_body: int,
        grid_x0: float,
        grid_y0: float,
        cell: float,
        nx: int,
        ny: int,
        cell_geoms: wp.array2d[int],
        robot_geoms: wp.array[int],
        ncollision_out: wp.array[int],
        collision_pair_out: wp.array[wp.vec2i],
        collision_pairid_out: wp.array[wp.vec2i],
        collision_worldid_out: wp.array[int],
    ):
        worldid, slot, r = wp.tid()
        base = xpos_in[worldid, base_body]
        if not (wp.isfinite(base[0]) and wp.isfinite(base[1])):
            return
        # points beyond the grid take the border cell, whose window reaches to infinity outwards
        ix = int(wp.clamp(wp.floor((base[0] - grid_x0) / cell), 0.0, float(nx - 1)))
        iy = int(wp.clamp(wp.floor((base[1] - grid_y0) / cell), 0.0, float(ny - 1)))
        terrain = cell_geoms[ix * ny + iy, slot]
        if terrain < 0:
            return
        robot = robot_geoms[r]
        g1 = wp.min(terrain, robot)
        g2 = wp.max(terrain, robot)
        pairid = nxn_pairid[upper_tri_index(ngeom, g1, g2)]
        # -2: excluded (contype/conaffinity, parent, <exclude>); an explicit <pair> or a collision sensor's pair is
        # MuJoCo Warp's own (kept in its all-pairs list)
        if pairid[0] != -1 or pairid[1] >= 0:
            return
        if wp.static(pair_filter)(geom_aabb, geom_rbound, geom_margin, geom_gap, pair_margin, pair_gap, geom_xpos_in,
                                  geom_xmat_in, g1, g2, pairid[0], worldid):
            _add_geom_pair(naconmax_in, g1, g2, geom_type[g1], geom_type[g2], worldid, pairid, ncollision_out,
                           collision_pair_out, collision_pairid_out, collision_worldid_out)

    return kernel


def static_geom_boxes(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-frame axis-aligned boxes of the geoms fixed to the world (their pose does not depend on ``qpos``).

    Returns:
        ids (k,) the static geoms; lo_w, hi_w (k, 3) [m] their boxes, grown by the geom's margin + gap; a plane
        (unbounded) spans everything.
    """
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    ids = np.flatnonzero(model.body_weldid[model.geom_bodyid] == 0)
    R = data.geom_xmat[ids].reshape(-1, 3, 3)
    center_w = data.geom_xpos[ids] + np.einsum("gij,gj->gi", R, model.geom_aabb[ids, :3])
    half_w = np.einsum("gij,gj->gi", np.abs(R), model.geom_aabb[ids, 3:])
    half_w += (model.geom_margin[ids] + model.geom_gap[ids])[:, None]
    half_w[model.geom_type[ids] == mujoco.mjtGeom.mjGEOM_PLANE] = np.inf
    return ids, center_w - half_w, center_w + half_w


def terrain_cells(model: mujoco.MjModel, cell: float, margin: float) -> tuple[RegionGrid, np.ndarray]:
    """Square cells over the static geoms' xy extent and the static geoms meeting each cell grown by ``margin``.

    Returns:
        grid: the cells (``RegionGrid``: row-major, x major; the border cells reach to infinity outwards).
        cell_geoms: (num_cells, K) int32 static geom ids of each cell in model order, padded with -1.
    """
    ids, lo, hi = static_geom_boxes(model)
    bounded = np.isfinite(lo[:, :2]).all(1) & np.isfinite(hi[:, :2]).all(1)
    if bounded.any():
        x0, y0 = lo[bounded, 0].min(), lo[bounded, 1].min()
        nx = max(1, int(np.ceil((hi[bounded, 0].max() - x0) / cell - 1e-9)))
        ny = max(1, int(np.ceil((hi[bounded, 1].max() - y0) / cell - 1e-9)))
    else:
        x0 = y0 = 0.0
        nx = ny = 1
    grid = RegionGrid(float(x0), float(y0), cell, nx, ny, margin)
    x_lo, x_hi = x0 + np.arange(nx) * cell - margin, x0 + (np.arange(nx) + 1) * cell + margin
    y_lo, y_hi = y0 + np.arange(ny) * cell - margin, y0 + (np.arange(ny) + 1) * cell + margin
    x_lo[0], x_hi[-1], y_lo[0], y_hi[-1] = -np.inf, np.inf, -np.inf, np.inf
    in_x = (hi[None, :, 0] >= x_lo[:, None]) & (lo[None, :, 0] <= x_hi[:, None])  # (nx, k)
    in_y = (hi[None, :, 1] >= y_lo[:, None]) & (lo[None, :, 1] <= y_hi[:, None])  # (ny, k)
    member = (in_x[:, None, :] & in_y[None, :, :]).reshape(nx * ny, len(ids))
    width = max(1, int(member.sum(1).max()))
    cell_geoms = np.full((nx * ny, width), -1, dtype=np.int32)
    for c, row in enumerate(member):  # once at build time, a few thousand cells
        found = ids[row]
        cell_geoms[c, :len(found)] = found
    return grid, cell_geoms


class TerrainCulling:
    """Per-world terrain culling installed on a MuJoCo Warp model (module docstring).

    Installing it changes ``m``: its all-pairs list (``nxn_geom_pair_filtered``) keeps only the pairs without a
    static geom, and ``m.callback.contactfilter`` runs :meth:`collide`.

    Args:
        model: the host model ``m`` was put from.
        m: the MuJoCo Warp model (on the current Warp device).
        naconmax: contacts allocated for all worlds (``Data.naconmax``): the size of the candidate buffer.
        base_body: the robot's base body id (the cell lookup).
        cell: cell side [m].
        margin: [m] geometry kept around a cell; > ``ROBOT_REACH + OBB_SLACK``.
    """

    def __init__(self, model: mujoco.MjModel, m, naconmax: int, base_body: int, cell: float = CELL,
                 margin: float = 1.0):
        if cell <= 0.0:
            raise ValueError(f"terrain culling cell must be > 0 m, got {cell}")
        if m.callback.contactfilter is not None:
            raise ValueError("the MuJoCo Warp model already has a contactfilter callback")
        self.base_body = base_body
        pairs, pairid = m.nxn_geom_pair_filtered.numpy(), m.nxn_pairid_filtered.numpy()
        static = model.body_weldid[model.geom_bodyid] == 0
        # explicit <pair>s and collision-sensor pairs stay with MuJoCo Warp (their own margins, always emitted)
        culled = (static[pairs[:, 0]] != static[pairs[:, 1]]) & (pairid[:, 0] == -1) & (pairid[:, 1] < 0)
        static_of = np.where(static[pairs[culled, 0]], pairs[culled, 0], pairs[culled, 1])
        self.robot_geoms = np.unique(np.where(static[pairs[culled, 0]], pairs[culled, 1], pairs[culled, 0]))
        reach = ROBOT_REACH + OBB_SLACK + float((model.geom_margin + model.geom_gap)[self.robot_geoms].max(initial=0.0))
        if margin <= reach:
            raise ValueError(f"terrain culling margin {margin} m must exceed the robot's reach {reach:.3f} m "
                             "(ROBOT_REACH + OBB_SLACK + its geoms' contact margins)")
        self.grid, cell_geoms = terrain_cells(model, cell, margin)
        pairs_of = np.bincount(static_of, minlength=model.ngeom)  # culled pairs each static geom is in
        self.cell_tests = np.where(cell_geoms >= 0, pairs_of[np.maximum(cell_geoms, 0)], 0).sum(1)
        """(num_cells,) robot-terrain pair tests of a world whose base is in each cell."""
        self.num_all_pairs = len(pairs)
        """Pairs per world of MuJoCo Warp's all-pairs broadphase on this model."""
        self.num_kept = int((~culled).sum())
        """Pairs per world left to MuJoCo Warp's own broadphase (the robot's self-collision pairs)."""
        self._cell_geoms = wp.array(cell_geoms, dtype=int)
        self._robot_geoms = wp.array(self.robot_geoms.astype(np.int32), dtype=int)
        self._ctx = CollisionContext(collision_pair=wp.empty(naconmax, dtype=wp.vec2i),
                                     collision_pairid=wp.empty(naconmax, dtype=wp.vec2i),
                                     collision_worldid=wp.empty(naconmax, dtype=int))
        m.nxn_geom_pair_filtered = wp.array(pairs[~culled], dtype=wp.vec2i)
        m.nxn_pairid_filtered = wp.array(pairid[~culled], dtype=wp.vec2i)
        m.callback.contactfilter = self.collide

    def collide(self, m, d) -> None:
        """Robot-terrain contacts of every world, appended to ``d.contact`` (MuJoCo Warp calls it after its pass)."""
        if len(self.robot_geoms) == 0:
            return
        d.ncollision.zero_()  # the candidates of this pass only; MuJoCo Warp's contacts stay in d.contact
        kernel = _culled_broadphase(int(m.opt.broadphase_filter), m.geom_aabb.shape[0], m.geom_rbound.shape[0],
                                    m.geom_margin.shape[0], m.geom_gap.shape[0], m.pair_margin.shape[0],
                                    m.pair_gap.shape[0])
        g, ctx = self.grid, self._ctx
        wp.launch(kernel, dim=(d.nworld, self._cell_geoms.shape[1], len(self.robot_geoms)),
                  inputs=[m.ngeom, m.geom_type, m.geom_aabb, m.geom_rbound, m.geom_margin, m.geom_gap, m.pair_margin,
                          m.pair_gap, m.nxn_pairid, d.xpos, d.geom_xpos, d.geom_xmat, d.naconmax, self.base_body,
                          g.x0, g.y0, g.cell, g.nx, g.ny, self._cell_geoms, self._robot_geoms],
                  outputs=[d.ncollision, ctx.collision_pair, ctx.collision_pairid, ctx.collision_worldid])
        _narrowphase(m, d, ctx)

    def pairs_tested(self, xpos: torch.Tensor) -> torch.Tensor:
        """(nworld,) pair tests per world at the current positions: MuJoCo Warp's kept pairs plus the robot
        against its cell's terrain geoms. ``xpos``: (nworld, nbody, 3) [m] ``Data.xpos``."""
        base = xpos[:, self.base_body, :2].double().cpu().numpy()
        tests = self.cell_tests[self.grid.cells(base[:, 0], base[:, 1])] + self.num_kept
        return torch.as_tensor(tests)


def collision_stats(m, d, culling: TerrainCulling | None = None) -> dict[str, float | int | str]:
    """What the last collision pass of every world used, for sizing ``nconmax``/``njmax`` and checking the
    broadphase (host reads: not for a hot loop).

    Returns:
        broadphase: ``culled`` (:class:`TerrainCulling`) or MuJoCo Warp's (``nxn``, ``sap_tile``, ``sap_segmented``);
        pairs_tested_max / _mean: broadphase pair tests per world; pairs_all: what the all-pairs broadphase tests;
        candidates: pairs passed to the narrowphase by the last pass, all worlds (the culled pass alone when culling);
        candidates_max: the most of them in one world (culling only; -1 otherwise: MuJoCo Warp keeps its own);
        contacts_max / _mean: contacts per world; nefc_max / _mean: constraint rows per world;
        nconmax, njmax: allocated per world; overflow: MuJoCo Warp's overflow bits, OR over the worlds.
    """
    nworld = d.nworld
    nacon = min(int(d.nacon.numpy()[0]), d.naconmax)
    worldid = wp.to_torch(d.contact.worldid)[:nacon].long().cpu()
    contacts = torch.bincount(worldid, minlength=nworld).double()
    nefc = wp.to_torch(d.nefc).double().cpu()
    if culling is None:
        tests = torch.full((nworld,), float(m.nxn_geom_pair_filtered.shape[0]), dtype=torch.float64)
        name, pairs_all = mjw.BroadphaseType(int(m.opt.broadphase)).name.lower(), tests[0].item()
    else:
        tests, name, pairs_all = culling.pairs_tested(wp.to_torch(d.xpos)).double(), "culled", culling.num_all_pairs
    candidates = min(int(d.ncollision.numpy()[0]), d.naconmax)
    candidates_max = -1
    if culling is not None:
        cand_world = wp.to_torch(culling._ctx.collision_worldid)[:candidates].long().cpu()
        candidates_max = int(torch.bincount(cand_world, minlength=nworld).max())
    overflow = int(np.bitwise_or.reduce(d.overflow.numpy()))
    return {"broadphase": name, "pairs_tested_max": int(tests.max()), "pairs_tested_mean": float(tests.mean()),
            "pairs_all": int(pairs_all), "candidates": candidates, "candidates_max": candidates_max,
            "contacts_max": int(contacts.max()), "contacts_mean": float(contacts.mean()),
            "nefc_max": int(nefc.max()), "nefc_mean": float(nefc.mean()),
            "nconmax": d.naconmax // nworld, "njmax": int(d.njmax), "overflow": overflow}
