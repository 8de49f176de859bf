"""Terrain culling on the MuJoCo Warp backend (``sim/warp_collision.py``) against MuJoCo Warp's all-pairs broadphase.

Skipped without MuJoCo Warp (the optional ``[gpu]`` extra). The rough-terrain test builds two ``warp-cpu``
backends on the rough task's terrain (~3 000 static geoms): with terrain regions (culled) and without (MuJoCo
Warp's all-pairs broadphase, what the backend did before culling), and compares them.
"""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.sim.interface import SimConfig
from dls_quadruped.sim.regions import RegionConfig
from dls_quadruped.sim.registry import make_backend
from dls_quadruped.sim.terrain import TerrainConfig, build_scene
from dls_quadruped.sim.terrain_tiles import TERRAIN_TYPES

pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")

# after the skip: the module imports MuJoCo Warp
from dls_quadruped.sim.warp_collision import terrain_cells

ROUGH = TerrainConfig(types=TERRAIN_TYPES, num_rows=10, step_height=(0.05, 0.25))
"""The rough task's terrain (``tasks/rough.yaml``): every tile type, 10 rows."""


def _boxes_model(xs: list[float]) -> mujoco.MjModel:
    """A free sphere and static 0.2 m boxes centred at (x, 0, -0.1) for each x."""
    boxes = "".join(f'<geom type="box" size="0.1 0.1 0.1" pos="{x} 0 -0.1"/>' for x in xs)
    return mujoco.MjModel.from_xml_string(f'<mujoco><worldbody>{boxes}<body><freejoint/>'
                                          '<geom type="sphere" size="0.05"/></body></worldbody></mujoco>')


def test_a_cell_lists_exactly_the_static_geoms_within_margin_of_it():
    """Boxes spanning x in [-0.1, 0.1], [1.9, 2.1] and [4.9, 5.1]; 1 m cells from x = -0.1 (6 up to 5.9), grown by
    0.5 m: cell 0 [-inf, 1.4] holds box 0 (the border cells reach outwards), cell 1 [0.4, 2.4] box 1, cell 2
    [1.4, 3.4] box 1, cell 3 [2.4, 4.4] none, cell 4 [3.4, 5.4] box 2, cell 5 [4.4, inf] box 2."""
    model = _boxes_model([0.0, 2.0, 5.0])
    grid, cell_geoms = terrain_cells(model, cell=1.0, margin=0.5)
    assert (grid.x0, grid.nx, grid.ny) == (pytest.approx(-0.1), 6, 1)  # x from -0.1 to 5.1: 5.2 m -> 6 cells
    lists = [sorted(int(g) for g in row if g >= 0) for row in cell_geoms]
    assert lists == [[0], [1], [1], [], [2], [2]]


@pytest.fixture(scope="module")
def rough():
    model, terrain = build_scene(ROUGH)
    return model, terrain


def _contacts(sim) -> list[set[tuple[int, int]]]:
    """Per world, the set of (geom1, geom2) in contact."""
    d = sim.d
    nacon = min(int(d.nacon.numpy()[0]), d.naconmax)
    geom, world = d.contact.geom.numpy()[:nacon], d.contact.worldid.numpy()[:nacon]
    out = [set() for _ in range(sim.num_envs)]
    for (g1, g2), w in zip(geom, world):
        out[w].add((int(g1), int(g2)))
    return out


@pytest.mark.slow
def test_culling_tests_few_pairs_and_keeps_the_contacts_on_every_tile_type(rough):
    """One robot per tile type (row 6), standing off the spawn platform where it meets the tile's relief, 0.4 s
    on the standing references: the culled backend tests <= 2 000 pairs per world (all pairs: 39 079), finds the
    same contacts (at the end: robots that started above a lower tread have landed), and the base positions follow the
    all-pairs backend within 1e-3 m
    (measured: bit for bit on warp-cpu, where the contacts come in the same order)."""
    model, terrain = rough
    n = len(TERRAIN_TYPES)
    xy = terrain.tile_origins_w[6, :, :2] + np.array([1.8, 1.3])  # off the 2 m platform
    z = terrain.height_at(torch.as_tensor(xy[:, 0]), torch.as_tensor(xy[:, 1])).numpy() + model.key_qpos[0, 2]
    pose = {"base_pos_w": np.c_[xy, z], "base_quat_w": np.tile([1.0, 0, 0, 0], (n, 1)),
            "joint_pos": np.tile(model.key_qpos[0, 7:19], (n, 1))}
    out = {}
    for culled in (False, True):
        cfg = SimConfig(regions=RegionConfig(ROUGH) if culled else None, nconmax=64, njmax=256)
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # no contact or row overflow
            with make_backend("warp-cpu", model, n, cfg) as sim:
                sim.reset(np.arange(n), **pose)
                traj = [sim.step(4).base_pos_w.clone() for _ in range(20)]
                stats, contacts = sim.collision_stats(), _contacts(sim)
                out[culled] = stats, contacts, torch.stack(traj), sim.state.diverged.clone()
    (all_stats, all_contacts, all_traj, all_div), (cull_stats, cull_contacts, cull_traj,
                                                   cull_div) = out[False], out[True]
    assert all_stats["broadphase"] == "nxn" and all_stats["pairs_tested_max"] == 39079
    assert cull_stats["broadphase"] == "culled" and cull_stats["pairs_tested_max"] <= 2000
    assert cull_stats["pairs_all"] == 39079
    print(all_stats, cull_stats, sep="\n")
    assert all(len(c) > 0 for c in all_contacts)  # every robot touches its tile's relief
    assert cull_contacts == all_contacts
    assert not all_div.any() and not cull_div.any()
    torch.testing.assert_close(cull_traj, all_traj, rtol=0, atol=1e-3)


# ---------------------------------------------------------------------------- contact and constraint sizes
@pytest.fixture(scope="module")
def plane():
    from dls_quadruped.robots.aliengo import constants as C

    return mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))


def test_a_robot_out_of_constraint_rows_is_flagged_diverged_and_reported_once(plane):
    """njmax = 8 rows: the standing robot 0 needs 16 (4 feet x 4 pyramidal rows), robot 1 in the air none. Only
    robot 0 is flagged (and frozen) after the step, with one warning; its reset clears the flag."""
    with make_backend("warp-cpu", plane, 2, SimConfig(njmax=8)) as sim:
        sim.check_every = 1  # the host-side check (the warning) at every step call
        key = plane.key_qpos[0]
        sim.reset([1], base_pos_w=[[0.0, 0.0, 2.0]], base_quat_w=key[None, 3:7], joint_pos=key[None, 7:19])
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            state = sim.step(2).clone()
            sim.step(2)
        assert [str(w.message)[:40] for w in record] == ["MuJoCo Warp ran out of contacts or const"]
        assert state.diverged.tolist() == [True, False]
        sim.reset([0], base_pos_w=[[0.0, 0.0, 2.0]], base_quat_w=key[None, 3:7], joint_pos=key[None, 7:19])
        assert sim.step(1).diverged.tolist() == [False, False]


def test_a_shared_contact_overflow_flags_every_robot(plane):
    """nconmax = 1: two standing robots find 8 foot contacts in a buffer of 2. The buffer is shared, so MuJoCo Warp
    cannot say whose contacts were dropped: every robot is flagged."""
    with make_backend("warp-cpu", plane, 2, SimConfig(nconmax=1)) as sim:
        sim.check_every = 1
        with pytest.warns(RuntimeWarning, match="ran out of contacts"):
            assert sim.step(4).diverged.tolist() == [True, True]  # the keyframe's feet touch down in a step or two
        assert sim.collision_stats()["nconmax"] == 1


def test_scene_sizes_reach_the_warp_backend():
    """``scene.nconmax`` / ``njmax`` of a task file are the backend's allocation per robot."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    task = load_task("base", overrides={"scene": {"backend": "warp-cpu", "nconmax": 12, "njmax": 40}})
    env = LocomotionEnv(task, num_envs=2, verbose=False)
    try:
        stats = env.scene.sim.collision_stats()
        assert (stats["nconmax"], stats["njmax"], stats["broadphase"]) == (12, 40, "nxn")  # a plane: nothing to cull
    finally:
        env.close()
