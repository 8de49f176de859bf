"""Per-robot terrain regions (``sim/regions.py``): a region model holds every terrain geom near its
cell, and robots simulated on region models move and push on the ground exactly as on the whole
terrain, on every tile type and across cell and tile borders."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim
from dls_quadruped.sim.regions import ROBOT_REACH, RegionConfig, build_region_models
from dls_quadruped.sim.terrain import TerrainConfig, build_scene
from dls_quadruped.sim.terrain_geometry import TERRAIN_GEOM_PREFIX

# every tile type, small tiles (cell = 2 m): many cell and tile borders within a few metres
CFG = TerrainConfig(types=("flat", "rugged", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down"),
                    num_rows=2, tile_size=4.0, border=1.0, platform=1.0, slope=(0.2, 0.4), box_height=(0.05, 0.1),
                    step_height=(0.05, 0.1), step_width=0.4, seed=3)


@pytest.fixture(scope="module")
def scene():
    model, terrain = build_scene(CFG)
    return model, terrain, build_region_models(CFG, model)


def _world_boxes(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """name -> (x0, x1, y0, y1) world xy bounds of every terrain geom, from MuJoCo's compiled boxes."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    out = {}
    for g in range(model.ngeom):
        name = model.geom(g).name
        if not name.startswith(TERRAIN_GEOM_PREFIX):
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half + centre
        w = corners @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        out[name] = np.array([w[:, 0].min(), w[:, 0].max(), w[:, 1].min(), w[:, 1].max()])
    return out


def test_region_models_hold_the_geoms_near_their_cell(scene):
    model, _, regions = scene
    full = _world_boxes(model)
    assert len({(m.ngeom, m.nbvh) for m in regions.models}) == 1  # one MjData layout
    assert regions.num_terrain < 0.6 * len(full)  # the point: fewer geoms than the whole terrain (÷ 18 for rough)
    for c, m in enumerate(regions.models):
        x0, x1, y0, y1 = regions.grid.window(c)
        near = {n for n, (a0, a1, b0, b1) in full.items() if a1 > x0 + 1e-6 and a0 < x1 - 1e-6
                and b1 > y0 + 1e-6 and b0 < y1 - 1e-6}
        kept = _world_boxes(m)
        assert near <= set(kept), f"cell {c} lacks {sorted(near - set(kept))[:5]}"
        for name, bounds in kept.items():  # the same geom, in the same place
            np.testing.assert_allclose(bounds, full[name], atol=1e-9)


def test_robot_stays_within_reach_of_its_base():
    """ROBOT_REACH bounds every robot collision geom's horizontal distance from the base, over random
    joint angles within the limits and any body orientation up to 90 deg of tilt."""
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    lim = np.array(C.JOINT_RANGES)
    robot = np.flatnonzero((model.geom_bodyid > 0) & ((model.geom_contype | model.geom_conaffinity) > 0))
    worst = 0.0
    for _ in range(2000):
        data.qpos[:3] = 0.0
        q = rng.normal(size=4)
        q[1:3] *= rng.uniform(0, 1)  # tilts of all sizes
        data.qpos[3:7] = q / np.linalg.norm(q) if q[0] ** 2 > 0.5 * (q @ q) else [1, 0, 0, 0]
        data.qpos[7:19] = rng.uniform(lim[:, 0], lim[:, 1])
        mujoco.mj_kinematics(model, data)
        reach = np.linalg.norm(data.geom_xpos[robot, :2], axis=1) + model.geom_rbound[robot]
        worst = max(worst, float(reach.max()))
    assert 0.4 < worst < ROBOT_REACH


def _run(model, regions: RegionConfig | None, pos: np.ndarray, vel: np.ndarray, steps: int) -> list[dict]:
    """Robots standing at ``pos`` (n, 3) with base velocity ``vel`` (n, 3), randomised friction and mass,
    ``steps`` calls of 4 physics steps: the states after each call."""
    n = len(pos)
    with VecSim(model, n, SimConfig(num_workers=0, regions=regions)) as sim:
        feet = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES]
        mu = np.linspace(0.4, 0.8, n)
        fr = np.repeat(model.geom_friction[None, feet], n, axis=0)
        fr[:, :, 0] = mu[:, None]
        sim.set_model_field("geom_friction", torch.arange(n), fr, index=feet)
        mass = np.repeat(model.body_mass[None], n, axis=0)
        mass[:, 1] *= np.linspace(0.9, 1.1, n)
        sim.set_model_field("body_mass", torch.arange(n), mass)
        quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
        joints = torch.as_tensor(C.NOMINAL_JOINT_POS).repeat(n, 1)
        sim.reset(torch.arange(n), torch.as_tensor(pos), quat, joints, base_lin_vel_w=torch.as_tensor(vel))
        out = []
        for _ in range(steps):
            s = sim.step(4)
            out.append({k: getattr(s, k).clone() for k in ("base_pos_w", "foot_force_w", "base_contact")})
    return out


def test_same_motion_and_contact_forces_as_the_whole_terrain(scene):
    """Robots on every tile type, and robots pushed across cell and tile borders (the region switches
    under them mid-run), give the whole terrain's states and foot forces."""
    model, terrain, _ = scene
    pos, vel = [], []
    for row in range(CFG.num_rows):
        for col in range(len(CFG.types)):
            x, y, z = terrain.tile_origins_w[row, col]
            pos.append([x, y, z + C.STANDING_BASE_HEIGHT + 0.01])  # standing on the tile centre
            vel.append([0.0, 0.0, 0.0])
            # walking at 1.5 m/s over a cell edge (+-1 m, +-3 m: another model), a tile border (+-2 m)
            for dx, dy in ((0.8, 0.0), (0.0, 1.85), (-2.8, -2.75)):
                p = (x + dx, y + dy)
                pos.append([*p, float(terrain.height_at(torch.tensor([p[0]]), torch.tensor([p[1]]))[0])
                            + C.STANDING_BASE_HEIGHT + 0.03])
                vel.append([1.5 * np.sign(dx), 1.5 * np.sign(dy), 0.0])
    pos, vel = np.array(pos), np.array(vel)
    whole = _run(model, None, pos, vel, steps=15)
    region = _run(model, RegionConfig(CFG), pos, vel, steps=15)
    cells = RegionConfig(CFG).build(model).grid.cells
    start, end = whole[0]["base_pos_w"].numpy(), whole[-1]["base_pos_w"].numpy()
    assert (cells(start[:, 0], start[:, 1]) != cells(end[:, 0], end[:, 1])).sum() >= 2 * len(CFG.types)  # switched
    for a, b in zip(whole, region):
        for k in a:
            torch.testing.assert_close(b[k], a[k], rtol=0, atol=1e-5, msg=k)


def test_redrawn_values_rewrite_the_robots_private_copy(scene):
    """A robot whose friction is drawn again keeps its private model copy (rewritten in place, no ~1 ms copy);
    another cell gives it a fresh copy of that cell's template; the values are the latest drawn."""
    from dls_quadruped.sim.regions import RobotRegions

    model, _, regions = scene
    rr = RobotRegions(regions, model, 2)
    centres = np.array([regions.grid.window(c) for c in (0, 1)])
    x = 0.5 * (centres[:, 0] + centres[:, 1])
    y = 0.5 * (centres[:, 2] + centres[:, 3])
    rr.update(x, y)
    foot = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES])
    first = np.repeat(model.geom_friction[None, foot].copy(), 2, axis=0)
    first[:, :, 0] = [[0.5], [0.7]]
    rr.set_field("geom_friction", np.arange(2), foot, first)
    copy0 = rr.models[0]
    assert copy0 is not regions.models[rr.cell[0]]  # a private copy
    second = first.copy()
    second[0, :, 0] = 0.9
    rr.set_field("geom_friction", np.array([0]), foot, second[:1])
    assert rr.models[0] is copy0  # rewritten in place
    rows = regions.robot_geom_ids(foot)
    np.testing.assert_array_equal(rr.models[0].geom_friction[rows, 0], 0.9)
    np.testing.assert_array_equal(rr.models[1].geom_friction[rows, 0], 0.7)
    np.testing.assert_array_equal(rr.field("geom_friction")[:, foot, 0], [[0.9] * 4, [0.7] * 4])
    rr.update(x[::-1].copy(), y[::-1].copy())  # the robots swap cells: fresh copies of the other templates
    assert rr.models[0] is not copy0
    np.testing.assert_array_equal(rr.models[0].geom_friction[rows, 0], 0.9)
