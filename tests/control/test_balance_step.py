"""The balance controller on terrain tiles (issue 8): on flat tiles it moves exactly as on MuJoCo's
plane, and given the true terrain height for its touch-down targets it walks up a 10 cm box step."""

from __future__ import annotations

import numpy as np
import pytest

from dls_quadruped.eval.balance_run import run_balance
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain import TerrainConfig, build_scene

# one stairs_down tile with a single step: a 2 m x 2 m box, 10 cm high, in the middle of flat ground
STEP = TerrainConfig(types=("stairs_down",), num_rows=1, tile_size=6.0, border=2.0, platform=2.0,
                     step_width=2.0, step_height=(0.1, 0.1))


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_balance_controller_walks_up_a_10cm_step():
    _, terrain = build_scene(STEP)
    cx, cy, top = terrain.tile_origins_w[0, 0]
    assert abs(top - 0.1) < 1e-6 and STEP.num_steps == 1
    # start 1.2 m before the step's edge (at cx - 1.0), walk +x at 0.3 m/s for 8 s (2.4 m); touch-downs at the
    # terrain's true height (run_balance's default on a terrain)
    run = run_balance(num_envs=4, stand_seconds=1.0, trot_seconds=8.0, cmd_vel_h=(0.3, 0.0, 0.0), terrain=STEP,
                      origin_w=(cx - 2.2, cy), joint_noise=0.02, seed=1)
    assert run.summary["num_fallen"] == 0
    x_end = run.qpos[-1, :, 0] - cx
    rear_hip = x_end - C.HIP_OFFSET_X
    assert np.all(rear_hip > -1.0 + 0.1), x_end  # the rear legs are past the edge too
    feet_z = run.foot_pos_w[-1, :, :, 2]
    assert np.all(np.abs(feet_z - (top + C.FOOT_RADIUS)) < 0.01), feet_z  # every foot stands on top
    assert np.all(np.abs(run.base_height[-1] - top - 0.34) < 0.03)  # standing height above the step


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_flat_tiles_behave_exactly_as_the_plane():
    """Same deterministic controller, same start relative to the ground: the state on the terrain's
    flat tiles (walking from one row into the next) equals the plane's to float32 round-off."""
    tiles = TerrainConfig(types=("flat", "rugged"), num_rows=3)
    _, terrain = build_scene(tiles)
    ox, oy = terrain.tile_origins_w[0, 0, :2]
    kw = {"num_envs": 2, "stand_seconds": 1.0, "trot_seconds": 6.0, "cmd_vel_h": (0.4, 0.0, 0.0),
          "joint_noise": 0.0, "seed": 0}
    plane = run_balance(**kw)
    start = (float(ox) + 3.0, float(oy))  # row 1 begins 1 m ahead, reached after ~3 s of trot
    tile = run_balance(terrain=tiles, origin_w=start, **kw)  # touch-downs at the terrain's true height
    assert tile.qpos[-1, :, 0].min() - start[0] > 1.5  # every robot is on row 1
    dx = np.abs(tile.qpos[..., 0] - start[0] - plane.qpos[..., 0]).max()
    d_rest = np.abs(tile.qpos[..., 2:] - plane.qpos[..., 2:]).max()  # height, orientation, joints
    assert dx < 1e-5 and d_rest < 1e-5, (dx, d_rest)
