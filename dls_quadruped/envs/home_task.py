"""The task the balance controller and the model-based baseline run in (``eval/balance_run.py``,
``closed_loop/baseline_run.py``): every robot starts in the home pose and plays one episode as long as the run.

It is the base task with every section that acts on the robots replaced: a plane (or a given terrain, every
robot colliding with the whole of it), robots placed by ``reset_home`` (``envs/mdp/events.py``: the home pose of
``sim.interface.home_state``), no termination (a fallen or diverged robot stays in its episode, as the
controllers' own checks count it), no reward, no observation term, no curriculum, one fixed command per robot
(what the controller is told, for anything that reads the env's command), the simulator in-process by default.
The env's step is the controller's period: ``decimation`` physics steps.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import mujoco

from dls_quadruped.envs.config import TaskConfig, load_task
from dls_quadruped.envs.sections import replace_sections
from dls_quadruped.robots.aliengo import constants as C

if TYPE_CHECKING:
    from dls_quadruped.sim.terrain import TerrainConfig


@functools.cache
def physics_dt() -> float:
    """[s] the scene's physics step (``option timestep`` of the MJCF), before any env is built: a controller's
    period in physics steps sets the env's ``decimation``."""
    return float(mujoco.MjSpec.from_file(str(C.SCENE_PATH)).option.timestep)


def _plain(value):
    """A dataclass field as task-file data: tuples (nested too) as lists."""
    return [_plain(v) for v in value] if isinstance(value, (tuple, list)) else value


def home_task(num_envs: int, seconds: float, decimation: int, command: tuple[float, float, float] = (0.0, 0.0, 0.0),
              terrain: TerrainConfig | None = None, seed: int = 0, joint_noise: float = 0.0,
              yaw: float | list[float] = 0.0, origin_xy: tuple[float, float] = (0.0, 0.0), num_workers: int = 0,
              backend: str = "cpu") -> TaskConfig:
    """The task described in the module docstring.

    Args:
        num_envs: robots; seconds: [s] the run's length (the episode's); decimation: physics steps per env step.
        command: (v_x, v_y [m/s], omega_z [rad/s]) of every robot.
        terrain: the ground (None: MuJoCo's plane); the robots stand on a flat patch at z = 0 around ``origin_xy``.
        seed: the env's seed and the joint noise's; joint_noise: [rad] uniform on the nominal joints;
        yaw: [rad] heading, one for all robots or one per robot; origin_xy: (x, y) [m] of every robot's base.
        num_workers: simulator worker processes (0: in-process); backend: the simulator (``sim/registry.py``).
    """
    terrain_data = ({f.name: _plain(getattr(terrain, f.name)) for f in dataclasses.fields(terrain)}
                    if terrain is not None else {"types": ["flat"]})
    yaw = yaw.tolist() if hasattr(yaw, "tolist") else yaw  # a tensor or array of headings
    yaw_data = [float(y) for y in yaw] if isinstance(yaw, (list, tuple)) else float(yaw)
    never = [10.0 * seconds, 10.0 * seconds]  # no command resampling within the run
    return replace_sections(load_task("base"), {
        "env": {"num_envs": num_envs, "episode_length_s": float(seconds), "decimation": decimation, "seed": seed},
        "scene": {"backend": backend, "num_workers": num_workers, "terrain_regions": False},
        "terrain": terrain_data,
        "observations": {},
        "commands": {"base_velocity": {"func": "fixed_velocity", "resampling_time_s": never,
                                       "params": {"values": [[float(c) for c in command]] * num_envs}}},
        "rewards": {},
        "terminations": {},
        "events": {"reset_home": {"mode": "reset", "params": {
            "joint_noise": float(joint_noise), "yaw": yaw_data, "origin_xy": [float(v) for v in origin_xy],
            "seed": seed}}},
        "curriculum": {},
    }, source="<home task: controller runs from the home pose>")
