"""Golden trajectories: short, seeded runs of every loop that steps the simulator.

``record()`` runs each one and returns flat ``name -> array``; ``python -m tests.golden.record`` writes
them to ``tests/golden/trajectories.npz`` with the machine they ran on (``fingerprint.json``).
``tests/test_golden.py`` reruns them: on the machine that recorded them the arrays must be
bit-identical; elsewhere (another CPU's floating-point paths) equal within a small tolerance.

A refactor that changes none of the physics, controllers or bookkeeping leaves them unchanged; a
change that is meant to alter them is recorded again in the same commit, with the reason.

The runs (CPU, in-process, seed 0):

* ``env``: the base task, 4 robots, 25 steps of seeded random latent actions (observations, rewards,
  terminations, base positions).
* ``rough``: the same on the rough task (terrain, noise, pushes, curriculum), 15 steps.
* ``eval``: ``eval.rollout.run_episodes`` of the committed base expert on the evaluation's flat task,
  2 episodes of 0.4 s.
* ``closed_loop``: ``closed_loop.episodes.run_controllers`` of the four controllers, 2 episodes of
  0.3 s, 256 MPC samples, 2 sampler seeds.
* ``balance``: the balance controller in the env (``eval.balance_run.run_balance``), 2 robots, 0.2 s
  stand + 0.7 s trot (one gait cycle, which its summary needs).
* ``baseline``: the model-based baseline in the env (``closed_loop.baseline_run.run_baseline``), 2 robots, 0.3 s.
"""

from __future__ import annotations

import hashlib
import json
import platform
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
POLICY = ROOT / "docs" / "policies" / "base_actor.pt"
STUDENT = ROOT / "docs" / "policies" / "base_student_first_spline_h10.pt"


def fingerprint() -> dict:
    """What decides whether two runs can be bit-identical: CPU model and flags, library versions."""
    flags = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and "model" not in locals():
                model = line.split(":", 1)[1].strip()
            if line.startswith("flags"):
                flags = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import mujoco

    return {"cpu": locals().get("model", platform.processor()),
            "cpu_flags_sha": hashlib.sha256(flags.encode()).hexdigest()[:16],
            "machine": platform.machine(), "python": sys.version.split()[0], "torch": torch.__version__,
            "numpy": np.__version__, "mujoco": mujoco.__version__, "torch_threads": torch.get_num_threads()}


def _env(name: str = "base", steps: int = 25) -> dict:
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    task = load_task(name)
    task.data["scene"]["num_workers"] = 0
    env = LocomotionEnv(task, num_envs=4, seed=0, verbose=False)
    try:
        g = torch.Generator().manual_seed(0)
        obs = [env.get_observations()["policy"].clone()]
        rew, term, trunc, pos = [], [], [], []
        for _ in range(steps):
            a = torch.randn(4, env.num_actions, generator=g) * 0.5
            o, r, d, extras = env.step(a)
            obs.append(o["policy"].clone())
            rew.append(r.clone())
            term.append(d.clone())
            trunc.append(extras["time_outs"].clone())
            pos.append(torch.cat([env.state.base_pos_w, env.state.base_quat_w], dim=-1).clone())
        return {"obs": torch.stack(obs).numpy(), "reward": torch.stack(rew).numpy(),
                "terminated": torch.stack(term).numpy().astype(np.int8),
                "time_out": torch.stack(trunc).numpy().astype(np.int8), "base_pos": torch.stack(pos).numpy()}
    finally:
        env.close()


def _eval() -> dict:
    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.eval.policy import load_policy
    from dls_quadruped.eval.rollout import run_episodes
    from dls_quadruped.eval.velocity_tracking import (
        TaskEvalOptions,
        flat_task,
        simple_commands,
    )

    opts = TaskEvalOptions(episodes=2, seed=0, num_workers=0, episode_length_s=0.4)
    cmd = simple_commands(2, 0)
    env = LocomotionEnv(flat_task(cmd, opts), num_envs=2, seed=0, verbose=False)
    try:
        torch.manual_seed(0)
        t = run_episodes(env, load_policy(POLICY, env))
    finally:
        env.close()
    return {"command": t.command, "velocity": t.velocity, "valid": t.valid.astype(np.int8), "reward": t.reward,
            "fell": t.fell.astype(np.int8), "length": t.length}


def _closed_loop() -> dict:
    from dls_quadruped.closed_loop.controllers import ControllerConfig
    from dls_quadruped.closed_loop.episodes import commands, run_controllers
    from dls_quadruped.mpc.config import SamplerConfig

    sampler = SamplerConfig(num_samples=256)
    configs = [ControllerConfig("rl_warm_start", student=STUDENT, sampler=sampler),
               ControllerConfig("naive_warm_start", sampler=sampler),
               ControllerConfig("rl_baseline", policy=POLICY),
               ControllerConfig("student", student=STUDENT, sampler=sampler)]
    traces = run_controllers(configs, commands(2, 0, None), 0.3, 0, 0, record_robots=1, sampler_seeds=2)
    out = {}
    for name, t in traces.items():
        for key in ("reward", "initial_cost", "initial_cost_terms", "vel_error", "power", "base_vel",
                    "rollout_cost", "mpc_initial_cost", "winner", "fell", "length", "qpos"):
            v = np.asarray(getattr(t, key))
            out[f"{name}.{key}"] = v.astype(np.int8) if v.dtype == bool else v
    return out


def _balance() -> dict:
    from dls_quadruped.eval.balance_run import run_balance

    run = run_balance(num_envs=2, stand_seconds=0.2, trot_seconds=0.7, seed=0)
    return {"qpos": np.asarray(run.qpos)}


def _baseline() -> dict:
    from dls_quadruped.closed_loop.baseline_run import run_baseline
    from dls_quadruped.mpc.baseline import BaselineConfig
    from dls_quadruped.mpc.config import SamplerConfig

    run = run_baseline(seconds=0.3, num_robots=2, cfg=BaselineConfig(sampler=SamplerConfig(num_samples=256)), seed=0)
    return {"qpos": np.asarray(run.qpos)}


RUNS = {"env": _env, "rough": lambda: _env("rough", 15), "eval": _eval, "closed_loop": _closed_loop,
        "balance": _balance, "baseline": _baseline}


def record(names: tuple[str, ...] = tuple(RUNS)) -> dict[str, np.ndarray]:
    """``run.key -> array`` of the named runs."""
    torch.set_num_threads(1)
    out = {}
    for name in names:
        for key, value in RUNS[name]().items():
            out[f"{name}.{key}"] = np.asarray(value)
    return out


def main() -> None:
    arrays = record()
    np.savez_compressed(HERE / "trajectories.npz", **arrays)
    (HERE / "fingerprint.json").write_text(json.dumps(fingerprint(), indent=1) + "\n")
    print(f"wrote {len(arrays)} arrays to {HERE / 'trajectories.npz'}")


if __name__ == "__main__":
    main()
