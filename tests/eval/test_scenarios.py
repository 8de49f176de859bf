"""The 7.1 scenarios: how their envs are built (terrain heights, rows, events, command grids),
each one end to end through the command line on a tiny run, and the command line's user errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.eval import cot, gait, omni, speed, stairs, survival
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.__main__ import main
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.eval.scenarios import SCENARIOS
from dls_quadruped.sim.terrain import TerrainConfig, build_scene

NEW = ("survival", "survival_sweep", "stairs", "speed", "omni", "cot", "gait")


def test_every_scenario_is_registered_with_a_small_default():
    assert set(NEW) <= set(SCENARIOS)
    for name in NEW:
        assert SCENARIOS[name].summary is not None and 1 <= SCENARIOS[name].default_episodes <= 128


def test_speed_grid_and_commands():
    assert speed.SPEEDS[0] == 0.25 and speed.SPEEDS[-1] == 2.5 and len(speed.SPEEDS) == 10
    cmd, group = speed.forward_commands((0.5, 1.5), 3)
    np.testing.assert_array_equal(cmd, [[0.5, 0, 0]] * 3 + [[1.5, 0, 0]] * 3)
    assert group.tolist() == [0, 0, 0, 1, 1, 1]


def test_stairs_terrain_puts_each_height_on_its_row():
    terrain = stairs.stairs_terrain((0.1, 0.2, 0.3))
    cfg = TerrainConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in terrain.items()})
    _, t = build_scene(cfg)
    n = cfg.num_steps
    assert n == 6 and cfg.num_rows == 3 and cfg.types == ("stairs_up",)
    x = torch.tensor(t.tile_origins_w[:, 0, 0], dtype=torch.float32)
    for y, expect in ((0.0, [-0.6, -1.2, -1.8]),          # the platform: 6 steps below the top
                      (1.1, [-0.5, -1.0, -1.5]),          # first tread (1.0-1.3 m from the centre)
                      (2.6, [0.0, 0.0, 0.0]),             # the top ring, at the border's level
                      (5.0, [0.0, 0.0, 0.0])):            # the flat border, 8 m wide
        z = t.height_at(x, torch.full_like(x, y))
        np.testing.assert_allclose(z.numpy(), expect, atol=1e-6)
    with pytest.raises(ValueError, match="evenly spaced"):
        stairs.stairs_terrain((0.05, 0.1, 0.3))


def test_stairs_commands_stay_in_the_climb_range():
    cmd, group = stairs.stairs_commands(stairs.HEIGHTS, 4, seed=1)
    assert cmd.shape == (40, 3) and group.tolist() == list(np.repeat(np.arange(10), 4))
    assert (cmd[:, 0] >= 0.3).all() and (cmd[:, 0] <= 0.5).all() and (cmd[:, 1:] == 0).all()


def test_stairs_env_places_every_robot_on_its_row_facing_the_border():
    from dls_quadruped.core.rotations import yaw_from_quat
    from dls_quadruped.envs.env import LocomotionEnv

    heights = (0.1, 0.2)
    cmd, group = stairs.stairs_commands(heights, 2, seed=0)
    env = LocomotionEnv(stairs.stairs_task(cmd, EvalOptions(num_workers=0), heights), num_envs=4, verbose=False)
    try:
        S.place_on_rows(env, group)
        assert env.scene.terrain_levels.tolist() == [0, 0, 1, 1]
        np.testing.assert_allclose(env.scene.env_origins[:, 2].numpy(), [-0.6, -0.6, -1.2, -1.2], atol=1e-6)
        np.testing.assert_allclose(yaw_from_quat(env.state.base_quat_w).numpy(), [math.pi / 2] * 4, atol=1e-5)
        np.testing.assert_allclose(env.command_manager.command.numpy(), cmd, atol=1e-6)
        assert env.cfg["observations"]["policy"]["noise_scale"] == 0.0 and list(env.cfg["events"]) == ["reset_robot"]
    finally:
        env.close()


def test_survival_terrain_and_events_are_harder_than_rough():
    rough = load_task("rough").data
    terrain = survival.survival_terrain()
    assert "flat" not in terrain["types"] and set(terrain["types"]) == set(rough["terrain"]["types"]) - {"flat"}
    # rough's ranges at difficulty 0.7 and 1: steps 5-25 cm (rough.yaml), rugged 1-8 cm, slope 0-0.4, boxes 2-15 cm
    assert terrain["step_height"] == pytest.approx([0.19, 0.25])
    assert terrain["rugged_amplitude"] == pytest.approx([0.059, 0.08])
    assert terrain["slope"] == pytest.approx([0.28, 0.4]) and terrain["box_height"] == pytest.approx([0.111, 0.15])
    ev = survival.survival_events()
    assert ev["friction"]["params"]["friction_range"] == pytest.approx([0.2, 1.0])  # rough 0.4-0.8
    assert ev["push"]["params"]["velocity_range"] == pytest.approx([-1.0, 1.0])     # rough +-0.5
    assert ev["push"]["interval_s"] == pytest.approx([4.0, 6.0])                    # rough 8-12 s
    assert ev["wrench"]["params"]["force_range"] == pytest.approx([-20.0, 20.0])
    assert ev["base_mass"] == rough["events"]["base_mass"]
    rows = survival.start_rows(50, 6)
    assert rows[:13].tolist() == [0] * 6 + [1] * 6 + [2] and rows.max() == survival.ROWS - 1
    task = survival.survival_task(np.zeros((4, 3)), EvalOptions(num_workers=0))
    assert task.data["observations"]["policy"]["noise_scale"] == 1.0
    # survival_sweep: rough's whole terrain range, row 0 at difficulty 0, with rough's own disturbances
    sweep = survival.survival_task(np.zeros((4, 3)), EvalOptions(num_workers=0), rows=survival.SWEEP_ROWS, hard=0.0,
                                   strength=survival.SWEEP_STRENGTH)
    assert sweep.data["terrain"]["step_height"] == pytest.approx([0.05, 0.25])
    assert sweep.data["terrain"]["rugged_amplitude"] == pytest.approx([0.01, 0.08])
    assert sweep.data["terrain"]["num_rows"] == 8 and set(sweep.data["terrain"]["types"]) == set(terrain["types"])
    ev1 = sweep.data["events"]
    assert ev1["friction"]["params"]["friction_range"] == pytest.approx([0.4, 0.8])
    assert ev1["push"]["params"]["velocity_range"] == pytest.approx([-0.5, 0.5])
    assert ev1["push"]["interval_s"] == pytest.approx([8.0, 12.0])
    assert ev1["wrench"]["params"]["force_range"] == pytest.approx([-10.0, 10.0])
    ev0 = survival.survival_events(0.0)  # no disturbance: nothing widened, no division by zero
    assert ev0["push"]["params"]["velocity_range"] == [0.0, 0.0] and ev0["push"]["interval_s"] == [8.0, 12.0]
    assert ev0["friction"]["params"]["friction_range"] == pytest.approx([0.6, 0.6])
    assert task.data["commands"]["base_velocity"]["func"] == "fixed_velocity"


class _Zero(torch.nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.zeros(x.shape[0], 28)


@pytest.fixture
def zero_policy(tmp_path, save_policy):
    return save_policy(_Zero(), 259, tmp_path / "zero.pt2")


@pytest.fixture
def tiny_grids(monkeypatch):
    """Two conditions per sweep."""
    for module in (speed, cot, gait):
        monkeypatch.setattr(module, "SPEEDS", (0.5, 1.0))
    monkeypatch.setattr(stairs, "HEIGHTS", (0.05, 0.1))
    monkeypatch.setattr(omni, "DIRECTIONS_DEG", (0, 180))
    monkeypatch.setattr(omni, "MAGNITUDES", (0.5, 1.0))
    monkeypatch.setattr(survival, "ROWS", 2)
    monkeypatch.setattr(survival, "SWEEP_ROWS", 2)


@pytest.mark.parametrize("name", NEW)
def test_command_line_end_to_end(name, zero_policy, tiny_grids, tmp_path):
    """Real env, zero-action policy, 2 episodes per condition of 0.4 s: JSON + PNG with counts and intervals."""
    out = tmp_path / "out"
    res = main(["--policy", str(zero_policy), "--scenario", name, "--episodes", "2", "--episode-length-s", "0.4",
                "--num-workers", "0", "--out", str(out)])
    saved = json.loads((out / f"{name}.json").read_text())
    assert (out / f"{name}.png").stat().st_size > 0 and saved["scenario"] == name == res["scenario"]
    assert saved["episode_steps"] == 20
    per = {"survival": None, "survival_sweep": None, "stairs": "per_height", "speed": "per_speed", "omni": "cells",
           "cot": "per_speed",
           "gait": "per_speed"}[name]
    if per is None:
        assert saved["survival"]["n"] == 2 and len(saved["per_row"]) == 2
        if name == "survival_sweep":  # rows at difficulty 0 and 1; a crossing inside [0, 1] with its interval
            assert [r["rough_difficulty"] for r in saved["per_row"]] == [0.0, 1.0]
            c = saved["survival_crossing_50"]
            assert 0.0 <= c["ci95"][0] <= c["ci95"][1] <= 1.0 and 0.0 <= c["rough_difficulty"] <= 1.0
    else:
        cells = saved[per]
        assert len(cells) == saved["conditions"] == (4 if name == "omni" else 2)
        assert saved["episodes"] == 2 * saved["conditions"]
        assert all(c["survival"]["n"] == 2 and len(c["survival"]["ci95"]) == 2 for c in cells)


class _Other(torch.nn.Module):
    """An actor of another observation layout (100 inputs) or action size."""

    def __init__(self, inputs: int, outputs: int):
        super().__init__()
        self.layer = torch.nn.Linear(inputs, outputs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layer(x)


def test_command_line_user_errors(tmp_path, one_line_error, save_policy):
    line = one_line_error(main, ["--policy", "p.pt", "--scenario", "nope"])
    assert "invalid choice: 'nope'" in line and all(n in line for n in ("simple", *NEW))
    line = one_line_error(main, ["--policy", str(tmp_path / "none.pt"), "--scenario", "speed"])
    assert "none.pt not found" in line
    assert "must be >= 1" in one_line_error(main, ["--policy", "p.pt", "--episodes", "0"])
    line = one_line_error(main, ["--policy", "p.pt", "--scenario", "survival", "--episodes", "3"])
    assert "survival needs a multiple of 2" in line
    common = ["--scenario", "simple", "--episodes", "2", "--episode-length-s", "0.1", "--num-workers", "0",
              "--out", str(tmp_path / "out")]
    save_policy(_Other(100, 28), 100, tmp_path / "obs100.pt2")
    line = one_line_error(main, ["--policy", str(tmp_path / "obs100.pt2"), *common])
    assert "takes 100 observation inputs" in line and "gives 259" in line
    save_policy(_Other(259, 12), 259, tmp_path / "act12.pt2")
    line = one_line_error(main, ["--policy", str(tmp_path / "act12.pt2"), *common])
    assert "outputs (12,) actions" in line and "takes 28" in line
    (tmp_path / "junk.pt").write_bytes(b"junk")
    assert "unreadable" in one_line_error(main, ["--policy", str(tmp_path / "junk.pt"), *common])
    line = one_line_error(main, ["--policy", str(_checkpoint_without_height_scan(tmp_path)), *common])
    assert "'policy': 72" in line and "'policy': 259" in line  # 259 - 187 height-scan values
    assert not (tmp_path / "out").exists()  # nothing written for a refused policy


def _checkpoint_without_height_scan(tmp_path):
    """An rsl-rl checkpoint of a task without the height scan (72 observations), one iteration."""
    import yaml

    from dls_quadruped.envs.config import TASKS_DIR
    from dls_quadruped.learning import train

    small = tmp_path / "blind.yaml"
    small.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "scene": {"num_workers": 0},
                                     "observations": {"policy": {"terms": {"height_scan": None}}},
                                     "agent": {"actor": {"hidden_dims": [8]}, "critic": {"hidden_dims": [8]}}}))
    run_dir = train.main(["--task", str(small), "--num-envs", "2", "--iterations", "1", "--run-dir",
                          str(tmp_path / "blind_run")])
    return run_dir / "model_0.pt"


def test_survival_env_places_robots_on_every_tile_row_by_row():
    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.robots.aliengo import constants as C

    cmd = np.zeros((12, 3))
    task = survival.survival_task(cmd, EvalOptions(num_workers=0), rows=2)
    env = LocomotionEnv(task, num_envs=12, verbose=False)
    try:
        S.place_on_rows(env, survival.start_rows(12, 6, rows=2))
        assert env.scene.terrain_types.tolist() == list(range(6)) * 2
        assert env.scene.terrain_levels.tolist() == [0] * 6 + [1] * 6
        origins = env.scene.tile_origins[env.scene.terrain_levels, env.scene.terrain_types]
        np.testing.assert_allclose(env.scene.env_origins.numpy(), origins.numpy())
        assert env.scene.terrain.tiles.param[1, 5] == pytest.approx(0.25)  # stairs_down, hardest row: 25 cm
        base_z = env.state.base_pos_w[:, 2].numpy()
        ground = env.scene.terrain.height_at(env.state.base_pos_w[:, 0], env.state.base_pos_w[:, 1]).numpy()
        # every robot at the reset height above the surface under it, not above another tile's (higher only
        # where a foot would start inside a bump or a step: events.spawn_height)
        assert (base_z - ground >= C.STANDING_BASE_HEIGHT + 0.02 - 1e-3).all()
        assert (base_z - ground < C.STANDING_BASE_HEIGHT + 0.02 + 0.3).all()
    finally:
        env.close()
