"""The home task (``envs/home_task.py``), its placement event ``reset_home`` and ``LocomotionEnv.apply_references``:
robots start exactly in ``sim.interface.home_state``'s pose, nothing ends their episode, and world references reach
the backend only inside ``step_controlled``, for exactly one env step of physics."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from dls_quadruped.envs.config import ConfigError
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.home_task import home_task, physics_dt
from dls_quadruped.envs.sections import replace_sections
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import home_state

YAW = [0.0, 1.0, -2.0]


@pytest.fixture(scope="module")
def env():
    task = home_task(3, 0.1, 2, (0.3, 0.0, 0.0), seed=4, joint_noise=0.05, yaw=YAW, origin_xy=(1.0, -2.0))
    env = LocomotionEnv(task, num_envs=3, seed=4, verbose=False)
    yield env
    env.close()


def _stand(env) -> tuple[torch.Tensor, ...]:
    """Standing references: all legs in stance, each carrying a quarter of the weight, feet where they are."""
    s = env.state
    force = torch.zeros(3, 4, 3)
    force[..., 2] = C.WEIGHT / 4
    return torch.zeros(3, 4), torch.ones(3, 4), s.foot_pos_w.clone(), force


def test_robots_start_in_the_home_pose(env):
    home = home_state(3, 4, 0.05, torch.tensor(YAW, dtype=torch.float64))
    s = env.state
    expected_pos = home["base_pos_w"] + torch.tensor([1.0, -2.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(s.base_pos_w.double(), expected_pos, atol=1e-6, rtol=0)
    torch.testing.assert_close(s.base_quat_w.double(), home["base_quat_w"], atol=1e-6, rtol=0)
    torch.testing.assert_close(s.joint_pos.double(), home["joint_pos"], atol=1e-6, rtol=0)
    assert float((home["joint_pos"] - torch.as_tensor(C.NOMINAL_JOINT_POS)).abs().max()) > 0.01  # the noise is there


def test_nothing_ends_an_episode_and_the_step_is_the_controllers_period(env):
    assert env.decimation == 2 and env.step_dt == pytest.approx(2 * physics_dt())
    assert env.termination_manager.terms == [] and env.reward_manager.terms == []
    assert env.command_manager.command[:, 0].tolist() == pytest.approx([0.3] * 3)


def test_references_reach_the_backend_inside_step_controlled_only(env):
    with pytest.raises(RuntimeError, match="apply_references runs inside step_controlled"):
        env.apply_references(*_stand(env), 2)
    with pytest.raises(RuntimeError, match="ran 1 physics steps"):
        env.step_controlled(lambda: env.apply_references(*_stand(env), 1))
    with pytest.raises(RuntimeError, match=r"1 \+ 2 physics steps exceed the policy step's 2"):
        env.step_controlled(lambda: [env.apply_references(*_stand(env), 1), env.apply_references(*_stand(env), 2)])
    t0 = env.state.time.clone()
    raw = env.action_manager.raw_action.clone()
    def physics() -> None:  # physics returns the non-finite mask or None, not the state
        env.apply_references(*_stand(env), 2)

    _, reward, dones, _ = env.step_controlled(physics)
    torch.testing.assert_close(env.state.time - t0, torch.full((3,), 2 * physics_dt()), atol=1e-6, rtol=0)
    assert not dones.any() and (reward == 0).all()
    assert torch.equal(env.action_manager.raw_action, raw)  # the action manager did not see them


def test_an_env_without_a_placement_event_is_refused():
    task = home_task(1, 0.1, 2)
    task = replace_sections(task, {"events": {}}, source="<test>")
    with pytest.raises(ConfigError, match="reset_robot or reset_home is required"):
        LocomotionEnv(task, num_envs=1, verbose=False)


def test_a_terrain_is_the_task_s_terrain_section():
    from dls_quadruped.sim.terrain import TerrainConfig

    tiles = TerrainConfig(types=("flat", "rugged"), num_rows=2)
    data = home_task(1, 0.1, 2, terrain=tiles).data
    assert data["terrain"]["types"] == ["flat", "rugged"] and data["terrain"]["num_rows"] == 2
    assert set(data["terrain"]) == {f.name for f in dataclasses.fields(tiles)}
    assert data["scene"]["terrain_regions"] is False  # every robot collides with the whole terrain
