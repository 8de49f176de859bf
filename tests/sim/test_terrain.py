"""Terrain: the batched height lookup equals MuJoCo's own ray cast on every terrain type."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.sim.height_scan import HeightScanConfig, height_scan, scan_pattern
from dls_quadruped.sim.terrain import TerrainConfig, build_scene
from dls_quadruped.sim.terrain_tiles import TERRAIN_TYPES, generate_tiles

SMALL = {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}


@pytest.fixture(scope="module")
def scene():
    cfg = TerrainConfig(types=TERRAIN_TYPES, seed=3, **SMALL)
    model, terrain = build_scene(cfg)
    return model, terrain


def _ray_heights(model: mujoco.MjModel, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Terrain height from vertical mj_ray casts (the robot is moved far away so rays only hit the ground)."""
    data = mujoco.MjData(model)
    data.qpos[:3] = (1e3, 1e3, 10.0)
    mujoco.mj_forward(model, data)
    gid = np.zeros(1, np.int32)
    out = np.empty(len(x))
    for i in range(len(x)):  # mj_ray is one ray per call; a test-only loop
        dist = mujoco.mj_ray(model, data, np.array([x[i], y[i], 20.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, gid)
        out[i] = 20.0 - dist
    return out


def test_height_lookup_matches_mj_ray_on_every_type(scene):
    model, terrain = scene
    rng = np.random.default_rng(0)
    half = 0.5 * terrain.cfg.tile_size
    for col, kind in enumerate(terrain.cfg.types):
        for row in range(terrain.num_rows):
            cx, cy = terrain.tile_origins_w[row, col, :2]
            x = cx + rng.uniform(-half, half, 60)
            y = cy + rng.uniform(-half, half, 60)
            z_ray = _ray_heights(model, x, y)
            z_lut = terrain.height_at(torch.tensor(x, dtype=torch.float32), torch.tensor(y, dtype=torch.float32))
            err = np.abs(z_lut.numpy() - z_ray).max()
            assert err < 1e-3, f"{kind} row {row}: max |lookup - mj_ray| = {err:.2e} m"


def test_types_have_their_shape(scene):
    _, terrain = scene
    cfg = terrain.cfg
    col = {k: i for i, k in enumerate(cfg.types)}
    hardest = cfg.num_rows - 1
    o = terrain.tile_origins_w
    # stairs: centre platform is num_steps * h below (up) / above (down) the tile edge (z = 0)
    n_steps = math.floor((0.5 * cfg.tile_size - 0.5 * cfg.platform) / cfg.step_width + 1e-9)
    assert o[hardest, col["stairs_up"], 2] == pytest.approx(-n_steps * cfg.step_height[1], abs=1e-3)
    assert o[hardest, col["stairs_down"], 2] == pytest.approx(n_steps * cfg.step_height[1], abs=1e-3)
    assert o[0, col["stairs_down"], 2] == pytest.approx(n_steps * cfg.step_height[0], abs=1e-3)
    summit = cfg.slope[1] * (0.5 * cfg.tile_size - 0.5 * cfg.platform)
    assert o[hardest, col["slope_down"], 2] == pytest.approx(summit, abs=1e-3)
    assert o[hardest, col["slope_up"], 2] == pytest.approx(-summit, abs=1e-3)
    assert o[:, col["flat"], 2] == pytest.approx(0.0, abs=1e-6)
    # one stair riser: walking +x from the stairs_down centre, the height drops by one step each tread
    cx, cy = o[hardest, col["stairs_down"], :2]
    xs = torch.tensor([cx + 0.5 * cfg.platform + 0.05 + k * cfg.step_width + 0.1 for k in range(3)])
    z = terrain.height_at(xs, torch.full_like(xs, float(cy)))
    assert torch.diff(z).numpy() == pytest.approx([-cfg.step_height[1]] * 2, abs=1e-3)


def test_rugged_amplitude_grows_with_row():
    cfg = TerrainConfig(types=("rugged",), seed=1, **SMALL)
    tiles = generate_tiles(cfg)
    amps = np.abs(tiles.rugged[:, 0]).max(axis=(1, 2))
    assert amps[0] <= cfg.rugged_amplitude[0] + 1e-9 and amps[-1] <= cfg.rugged_amplitude[1] + 1e-9
    assert amps[-1] > 0.5 * cfg.rugged_amplitude[1] and amps[0] < amps[-1]
    assert np.all(tiles.rugged[:, 0, [0, -1], :] == 0) and np.all(tiles.rugged[:, 0, :, [0, -1]] == 0)


def test_unknown_type_is_rejected():
    with pytest.raises(ValueError, match="allowed"):
        TerrainConfig(types=("lava",))


def test_flat_config_keeps_the_plane():
    model, terrain = build_scene(TerrainConfig(types=("flat",), **SMALL))
    assert terrain.is_plane and model.nhfield == 0
    assert float(terrain.height_at(torch.tensor([1.0]), torch.tensor([2.0]))) == 0.0


def test_height_scan_values_and_yaw_alignment(scene):
    _, terrain = scene
    cfg = HeightScanConfig()
    pattern = scan_pattern(cfg)
    assert cfg.shape == (17, 11) and pattern.shape == (187, 2)
    # a base at 0.9 m over a point of the flat column, yawed by 90 deg: scan = 0.9 - 0 - 0.5 everywhere
    col = terrain.cfg.types.index("flat")
    p = torch.tensor([[*terrain.tile_origins_w[1, col, :2], 0.9]], dtype=torch.float32)
    q = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]])
    scan = height_scan(terrain, pattern, p, q, cfg)
    assert scan.shape == (1, 187) and torch.allclose(scan, torch.full_like(scan, 0.4), atol=1e-5)
    # on stairs_down (summit at the centre) and yaw 90 deg, the first scan point (x=-0.8, y=-0.5 in yaw frame)
    # lies at world (x + 0.5, y - 0.8)
    col = terrain.cfg.types.index("stairs_down")
    ox, oy, oz = terrain.tile_origins_w[0, col]
    p = torch.tensor([[ox + 0.3, oy + 0.2, oz + 0.5]], dtype=torch.float32)
    scan = height_scan(terrain, pattern, p, q, cfg)
    z0 = terrain.height_at(torch.tensor([ox + 0.3 + 0.5]), torch.tensor([oy + 0.2 - 0.8]))
    expected = (p[0, 2] - z0 - 0.5).clamp(-1, 1)
    assert float(scan[0, 0]) == pytest.approx(float(expected), abs=1e-5)
    # clipping
    p_high = p.clone()
    p_high[0, 2] += 5.0
    assert torch.all(height_scan(terrain, pattern, p_high, q, cfg) == 1.0)
