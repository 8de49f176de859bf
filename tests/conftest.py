"""Fixtures shared by the test packages: environments, and the test helpers as fixtures (factories or
classes), so that no test module imports from another."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensordict import TensorDict

SMALL_TERRAIN = {"scene": {"num_workers": 0},
                 "terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}
"""Task overrides for a quick in-process base env: no simulator workers, a 3-row terrain."""


@pytest.fixture(scope="module")
def small_base_env():
    """The base task on 3 robots with :data:`SMALL_TERRAIN`, one per test module."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    e = LocomotionEnv(load_task("base", overrides=SMALL_TERRAIN), num_envs=3, verbose=False)
    yield e
    e.close()


# ------------------------------------------------------------------ command lines


@pytest.fixture
def one_line_error(capsys):
    """``one_line_error(main, argv) -> line``: run ``main(argv)`` as the command line does
    (``cli.run_cli``), expect exit status 2 and exactly one ``<prog>: error: ...`` line on stderr,
    no traceback anywhere; return that line."""
    from dls_quadruped.cli import run_cli

    def run(main, argv: list[str]) -> str:
        with pytest.raises(SystemExit) as exit_:
            run_cli(main, argv)
        assert exit_.value.code == 2
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in captured.err + captured.out, captured.err
        assert ": error: " in lines[0], captured.err
        return lines[0]

    return run


# ------------------------------------------------------------------ exported networks


@pytest.fixture(scope="session")
def save_policy():
    """``save_policy(module, input_size, path) -> path``: ``module`` exported as the package exports
    networks (a ``torch.export`` program, ``learning/policy_file.py``), e.g. a stand-in policy."""
    from dls_quadruped.learning.policy_file import save_program

    return save_program


# ------------------------------------------------------------------ MPC problems

FEET_W = torch.tensor([[0.24, 0.134, 0.0265], [0.24, -0.134, 0.0265], [-0.24, 0.134, 0.0265],
                       [-0.24, -0.134, 0.0265]])
"""(4, 3) [m] an AlienGo-like robot's feet under its hips, world frame, leg order FL, FR, RL, RR."""


def _standing(batch: int = 2, height: float = 0.33):
    """B robots standing at the origin, feet under the hips, commanded 0.5 m/s forward."""
    from dls_quadruped.mpc.cost import Refs
    from dls_quadruped.mpc.srbd import SRBDState

    state = SRBDState(
        com_pos_w=torch.tensor([[0.0, 0.0, height]]).repeat(batch, 1),
        com_vel_w=torch.zeros(batch, 3),
        euler=torch.zeros(batch, 3),
        ang_vel_b=torch.zeros(batch, 3),
        foot_pos_w=FEET_W.expand(batch, 4, 3).clone(),
    )
    refs = Refs(com_height_w=torch.full((batch,), height), lin_vel_w=torch.tensor([[0.5, 0.0]]).repeat(batch, 1),
                yaw_rate=torch.zeros(batch), foothold_w=FEET_W.expand(batch, 4, 3).clone())
    return state, refs


@pytest.fixture(scope="session")
def standing():
    """``standing(batch=2, height=0.33) -> (SRBDState, Refs)``: a standing AlienGo-like SRBD state and its
    references (0.5 m/s forward), fresh tensors on every call."""
    return _standing


@pytest.fixture(scope="session")
def feet_w() -> torch.Tensor:
    """(4, 3) [m] the standing robot's feet, world frame (:func:`standing`'s)."""
    return FEET_W.clone()


@pytest.fixture(scope="session")
def perturbed_standing():
    """``perturbed_standing(b, seed) -> (SRBDState, Refs, phase (B, 4))``: B standing robots with seeded
    perturbations of the state, the references and the footholds, and random gait phases."""
    from dls_quadruped.mpc.cost import Refs
    from dls_quadruped.mpc.srbd import SRBDState

    def make(b: int, seed: int):
        gen = torch.Generator().manual_seed(seed)
        state, refs = _standing(b)
        noise = lambda t, s: t + s * torch.randn(t.shape, generator=gen)
        state = SRBDState(noise(state.com_pos_w, 0.01), noise(state.com_vel_w, 0.1), noise(state.euler, 0.05),
                          noise(state.ang_vel_b, 0.1), noise(state.foot_pos_w, 0.01))
        refs = Refs(refs.com_height_w, noise(refs.lin_vel_w, 0.2), noise(refs.yaw_rate, 0.2),
                    noise(refs.foothold_w, 0.02))
        return state, refs, torch.rand(b, 4, generator=gen)

    return make


# ------------------------------------------------------------------ robot states


@pytest.fixture(scope="session")
def random_states():
    """``random_states(num, seed) -> (qpos (num, 19), qvel (num, 18))``: random MuJoCo states of the
    robot: any base pose, joints within limits, velocities of a few units."""
    from dls_quadruped.robots.aliengo import constants as C

    def make(num: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        qpos = np.zeros((num, 19))
        qpos[:, 0:3] = rng.uniform(-2.0, 2.0, (num, 3))
        quat = rng.standard_normal((num, 4))
        qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        lo, hi = C.JOINT_RANGES[:, 0], C.JOINT_RANGES[:, 1]
        qpos[:, 7:] = rng.uniform(lo, hi, (num, 12))
        qvel = rng.uniform(-3.0, 3.0, (num, 18))
        return qpos, qvel

    return make


# ------------------------------------------------------------------ distillation stand-ins


class _ScriptedEnv:
    """Env whose observation is (env id, step of its episode, episode number) and whose
    episode of env e lasts ``lengths[e]`` steps (then it resets); actions are recorded.

    The 'expert' :func:`_tag_expert` returns an action that encodes (env, step, episode), so a
    window's actions name the steps they came from.
    """

    num_actions = 28
    step_dt = 0.02
    max_episode_length = 750
    device = "cpu"

    def __init__(self, lengths: list[int]):
        self.num_envs = len(lengths)
        self.lengths = torch.tensor(lengths)
        self.t_ep = torch.zeros(self.num_envs, dtype=torch.long)
        self.episode = torch.zeros(self.num_envs, dtype=torch.long)
        self.applied: list[torch.Tensor] = []
        self.command_manager = SimpleNamespace(command=torch.zeros(self.num_envs, 3))  # read by envs.recorder

    def _obs(self) -> TensorDict:
        env_id = torch.arange(self.num_envs, dtype=torch.float32)
        obs = torch.stack([env_id, self.t_ep.float(), self.episode.float()], dim=1)
        return TensorDict({"policy": obs}, batch_size=[self.num_envs])

    def get_observations(self) -> TensorDict:
        return self._obs()

    def reset(self, seed=None, episode_keys=None):
        self.t_ep.zero_()
        return self._obs(), {}

    def step(self, actions: torch.Tensor):
        self.applied.append(actions.clone())
        self.t_ep += 1
        dones = self.t_ep >= self.lengths
        self.t_ep[dones] = 0
        self.episode[dones] += 1
        return self._obs(), torch.zeros(self.num_envs), dones.long(), {"time_outs": dones.clone()}


def _tag_expert(obs: torch.Tensor) -> torch.Tensor:
    """(B, 3) -> (B, 28): entry i = 10000 episode + 100 env + step + i / 100, unique per (env, episode, step)."""
    tag = 10000.0 * obs[:, 2] + 100.0 * obs[:, 0] + obs[:, 1]
    return tag[:, None] + torch.arange(28, dtype=torch.float32) / 100.0


class _LinearEnv:
    """s_{t+1} = A s_t + B a_t, no resets: with a = K s the expert's horizon is K (A + B K)^j s_t."""

    num_actions = 28
    step_dt = 0.02
    max_episode_length_s = 15.0
    max_episode_length = 750
    device = "cpu"

    def __init__(self, num_envs: int, A: torch.Tensor, B: torch.Tensor, seed: int = 0):
        self.num_envs, self.A, self.B = num_envs, A, B
        self.gen = torch.Generator().manual_seed(seed)
        self.s = torch.randn(num_envs, A.shape[0], generator=self.gen)
        self.command_manager = SimpleNamespace(command=torch.zeros(num_envs, 3))  # read by envs.recorder

    def get_observations(self) -> TensorDict:
        return TensorDict({"policy": self.s.clone()}, batch_size=[self.num_envs])

    def reset(self, seed=None, episode_keys=None):
        self.s = torch.randn(self.num_envs, self.A.shape[0], generator=self.gen)
        return self.get_observations(), {}

    def step(self, actions: torch.Tensor):
        self.s = self.s @ self.A.T + actions @ self.B.T
        dones = torch.zeros(self.num_envs, dtype=torch.long)
        return self.get_observations(), torch.zeros(self.num_envs), dones, {"time_outs": dones.bool()}


@pytest.fixture(scope="session")
def scripted_env():
    """``scripted_env(lengths) -> env``: the class :class:`_ScriptedEnv` (observations name the env,
    step and episode; env e's episodes last ``lengths[e]`` steps; applied actions are recorded)."""
    return _ScriptedEnv


@pytest.fixture(scope="session")
def tag_expert():
    """``tag_expert(obs (B, 3)) -> (B, 28)``: :func:`_tag_expert`, the scripted env's expert whose actions
    name the (env, episode, step) they were taken at."""
    return _tag_expert


@pytest.fixture(scope="session")
def linear_env():
    """``linear_env(num_envs, A, B, seed=0) -> env``: the class :class:`_LinearEnv`
    (s_{t+1} = A s_t + B a_t, no resets)."""
    return _LinearEnv


# ------------------------------------------------------------------ tiny training runs

REPO = Path(__file__).resolve().parents[1]
TINY_TASK = {
    "inherit": str(REPO / "tasks" / "_common.yaml"),
    "env": {"episode_length_s": 0.5},
    "scene": {"num_workers": 0},
    "commands": {"base_velocity": {"func": "uniform_velocity", "params": {
        "lin_vel_x": [0.0, 0.5], "lin_vel_y": [0.0, 0.0], "ang_vel_z": [0.0, 0.0]}}},
    "curriculum": {
        "speed": {"func": "command_speed_growth",
                  "params": {"reward_term": "track_lin_vel_xy", "threshold": -1.0, "step": 0.05, "max_speed": 9.0}},
        "penalties": {"func": "penalties_when_walking", "params": {
            "terms": ["action_rate"], "reward_term": "track_lin_vel_xy", "threshold": -1.0}},
    },
    "rewards": {"track_lin_vel_xy": {"weight": 1.5, "params": {"sigma": 0.5}}, "action_rate": {"weight": -2.5e-5}},
    "agent": {"actor": {"hidden_dims": [16]}, "critic": {"hidden_dims": [16]}},
}
"""A task whose episodes end after 0.5 s (25 policy steps), so each PPO iteration (24 steps per env) resets
robots and moves the curricula: the speed range grows by 0.05 m/s per batch of resets and the penalty
switch flips on the first reset (threshold -1)."""


@pytest.fixture(scope="session")
def write_task():
    """``write_task(dir, name="tiny", **sections) -> path``: :data:`TINY_TASK` with whole top-level
    sections replaced, written to ``dir/<name>.yaml``."""
    import yaml

    def write(directory: Path, name: str = "tiny", **changes) -> Path:
        path = Path(directory) / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**TINY_TASK, **changes}))
        return path

    return write


@pytest.fixture(scope="session")
def train_args():
    """``train_args(task, run_dir, *extra) -> argv`` of ``learning.train``: 4 robots, a checkpoint every iteration."""

    def argv(task: Path, run_dir: Path, *extra: str) -> list[str]:
        return ["--task", str(task), "--num-envs", "4", "--run-dir", str(run_dir), "--save-interval", "1", *extra]

    return argv


@pytest.fixture(scope="session")
def printed_curriculum():
    """``printed_curriculum(line) -> {name: value}``: the curriculum values of train's
    "resumed from ... curriculum {...}" (or "initialised ...") line."""
    import re

    def parse(line: str) -> dict[str, float]:
        return {k: float(v) for k, v in re.findall(r"'(\w+)': ([-\d.e]+)", line.split("curriculum", 1)[1])}

    return parse


def pytest_configure(config):
    """Under pytest-xdist (``make test`` runs two workers) each worker keeps torch to one thread: two workers of
    two threads each would oversubscribe a 2-core machine."""
    import os

    if os.environ.get("PYTEST_XDIST_WORKER"):
        torch.set_num_threads(1)
