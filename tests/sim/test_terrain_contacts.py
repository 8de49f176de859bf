"""Foot contacts on the terrain tiles: one contact whose normal is the surface normal, and the
same sink as on MuJoCo's plane (the height-field terrain gave 2-7 contacts tilted up to 50 deg)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain import TerrainConfig, build_scene

# a foot alone: the AlienGo foot sphere with the foot's contact parameters, free to move
FOOT_SCENE = f"""<mujoco>
  <option timestep="0.005" integrator="implicitfast"/>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05" friction="0.8 0.02 0.01"/>
    <body name="foot" pos="0 0 1"><freejoint/>
      <geom type="sphere" size="{C.FOOT_RADIUS}" mass="6.0" priority="1" solref="0.01 1" friction="0.8 0.02 0.01"/>
    </body>
  </worldbody>
</mujoco>"""

CFG = TerrainConfig(types=("flat", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down", "rugged"),
                    num_rows=2, tile_size=4.0, border=1.0, platform=1.0, slope=(0.2, 0.4), step_height=(0.1, 0.2),
                    step_width=0.4, seed=5)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("foot") / "foot.xml"
    path.write_text(FOOT_SCENE)
    plane = mujoco.MjModel.from_xml_string(FOOT_SCENE)
    model, terrain = build_scene(CFG, scene_path=path)
    return plane, model, terrain


def _contacts(model: mujoco.MjModel, centre: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """(normal, penetration) of every contact of the foot placed at ``centre`` (world)."""
    data = mujoco.MjData(model)
    data.qpos[:3] = centre
    mujoco.mj_forward(model, data)
    return [(np.array(c.frame[:3]), float(c.dist)) for c in data.contact[: data.ncon]]


def _surface_points(terrain, kind: str, row: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Points on one tile's surface away from every edge, with the surface's unit normal there."""
    col = CFG.types.index(kind)
    cx, cy, _ = terrain.tile_origins_w[row, col]
    half, hp, w, s = 0.5 * CFG.tile_size, 0.5 * CFG.platform, CFG.step_width, terrain.tiles.param[row, col]
    up = np.array([0.0, 0.0, 1.0])
    local: list[tuple[float, float, np.ndarray]] = []
    if kind == "flat":  # incl. the boundary to the next row: a flat column is one box, no seam there
        local = [(x, y, up) for x, y in ((0.0, 0.0), (1.3, -0.7), (-1.6, 1.2), (half, 0.3), (half + 0.004, -0.9))]
    elif kind in ("slope_up", "slope_down"):
        sign = 1.0 if kind == "slope_down" else -1.0
        for ang in (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi):  # mid-face of each of the four faces
            ex = np.array([math.cos(ang), math.sin(ang)])
            n = np.array([*(sign * s * ex), 1.0])
            local.append((*(0.5 * (hp + half) * ex), n / np.linalg.norm(n)))
        local.append((0.0, 0.0, up))  # the platform
    elif kind == "boxes":
        for iy, ix in ((1, 1), (3, 6), (6, 2)):
            local.append(((ix + 0.5) * CFG.box_size - half, (iy + 0.5) * CFG.box_size - half, up))
        local += [(0.0, 0.0, up), (0.005, -0.004, up)]  # the spawn point: one platform box, not 4 cell corners
    elif kind in ("stairs_up", "stairs_down"):
        for j in range(CFG.num_steps):  # middle of tread j along +x, -y
            mid = hp + (j + 0.5) * w
            local += [(mid, 0.0, up), (0.0, -mid, up)]
    out = []
    for x, y, n in local:
        xw, yw = cx + x, cy + y
        z = float(terrain.height_at(torch.tensor([xw], dtype=torch.float64), torch.tensor([yw], dtype=torch.float64)))
        out.append((np.array([xw, yw, z]), n))
    return out


@pytest.mark.parametrize("kind", ["flat", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down"])
@pytest.mark.parametrize("penetration", [0.001, 0.005])
def test_one_contact_along_the_surface_normal(scene, kind, penetration):
    _, model, terrain = scene
    for row in range(CFG.num_rows):
        for point, normal in _surface_points(terrain, kind, row):
            centre = point + normal * (C.FOOT_RADIUS - penetration)
            contacts = _contacts(model, centre)
            assert len(contacts) == 1, f"{kind} row {row} at {point}: {len(contacts)} contacts"
            n, dist = contacts[0]
            tilt = math.degrees(math.acos(min(1.0, abs(float(n @ normal)))))
            assert tilt < 0.5, f"{kind} row {row} at {point}: normal tilted {tilt:.2f} deg from the surface's"
            assert dist == pytest.approx(-penetration, abs=1e-4)


def test_resting_sink_on_a_flat_tile_equals_the_plane(scene):
    plane, model, terrain = scene

    def rest(m: mujoco.MjModel, xy: np.ndarray) -> float:
        d = mujoco.MjData(m)
        d.qpos[:3] = (*xy, C.FOOT_RADIUS + 0.01)
        for _ in range(400):
            mujoco.mj_step(m, d)
        assert np.abs(d.qvel).max() < 1e-3  # at rest
        return C.FOOT_RADIUS - float(d.qpos[2])

    sink_plane = rest(plane, np.zeros(2))
    for row in range(CFG.num_rows):
        origin = terrain.tile_origins_w[row, CFG.types.index("flat"), :2]
        for offset in ((0.0, 0.0), (0.37, -1.21)):
            assert rest(model, origin + offset) == pytest.approx(sink_plane, abs=1e-4)
