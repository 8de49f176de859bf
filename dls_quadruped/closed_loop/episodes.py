"""The closed loop's episodes: the scenarios' envs, every controller run on the same scheduled episodes,
their summaries and the plot (what ``python -m dls_quadruped.closed_loop``, the benches and the warm-start
experiments call).

Every controller gets a fresh env with the same seed and the same scheduled episodes (commands, starting
states, and any event or noise, ``envs/schedule.py``), so differences between controllers are paired per
episode. An MPC controller runs each episode with ``sampler_seeds`` independent sampler noise streams at once
(E x S robots in one batched env, robot s E + e playing episode e); a policy controller is deterministic and
runs each episode once.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
from dls_quadruped.closed_loop.loop import ClosedLoopTraces, run_closed_loop
from dls_quadruped.closed_loop.metrics import compare, summarize

DEFAULT_POLICY = Path("docs/policies/base_actor.pt")
"""The committed RL expert (``rl_baseline``)."""
DEFAULT_STUDENT = Path("docs/policies/base_student_first_spline_h10.pt")
"""The committed student of the default MPC (first-spline encoding, N = 10): ``rl_warm_start``, ``student``."""
SCENARIOS = ("simple", "pushes", "survival", "survival_sweep", "stairs")
"""Where the controllers run: ``simple`` = the base task on flat ground without noise or perturbation;
``pushes`` = the same with pushes of a given speed (``eval/pushes.py``);
``survival`` / ``survival_sweep`` = the eval suite's scenarios (``eval/survival.py``): their terrain
rows, disturbances (friction, wrench, pushes), observation noise and terminations; ``stairs`` = the
eval suite's staircase test (``eval/stairs.py``: a ``stairs_up`` column, one row per step height, every
robot on its row's platform facing the flight, no noise or perturbation)."""
STAIRS_HEIGHTS = (0.05, 0.10, 0.15, 0.20)
"""[m] the closed loop's default stairs step heights (5-20 cm), one terrain row each."""


def commands(episodes: int, seed: int, vx: float | None, scenario: str = "simple",
             heights: tuple[float, ...] = STAIRS_HEIGHTS) -> np.ndarray:
    """(E, 3) commands: the simple task's (mirrored pairs) or a fixed forward speed; on ``stairs`` the eval
    suite's (``eval.stairs.stairs_commands``): ``episodes`` per step height of ``heights``, height-major."""
    if scenario == "stairs":
        from dls_quadruped.eval.stairs import stairs_commands

        if vx is not None:
            raise ValueError(f"the stairs scenario draws its own forward commands; got vx {vx}")
        return stairs_commands(tuple(heights), episodes, seed)[0]
    from dls_quadruped.eval.velocity_tracking import simple_commands

    if vx is None:
        return simple_commands(episodes, seed)
    return np.tile([vx, 0.0, 0.0], (episodes, 1))


def stairs_rows(episodes: int, num_heights: int) -> np.ndarray:
    """(E,) terrain row of each stairs episode: height-major, E / H episodes per height (``commands``' order)."""
    if episodes % num_heights:
        raise ValueError(f"the stairs scenario plays the same number of episodes per height: {episodes} episodes "
                         f"are not a multiple of {num_heights} heights")
    return np.repeat(np.arange(num_heights), episodes // num_heights)


def _survival_layout(scenario: str) -> tuple[int, float, float]:
    from dls_quadruped.eval import survival as SV

    if scenario == "survival":
        return SV.ROWS, SV.HARD, SV.STRENGTH
    return SV.SWEEP_ROWS, 0.0, SV.SWEEP_STRENGTH


def make_env(cmds: np.ndarray, seconds: float, seed: int, num_workers: int, replicas: int = 1,
             scenario: str = "simple", heights: tuple[float, ...] = STAIRS_HEIGHTS, device: str = "cpu",
             backend: str = "cpu", overrides: dict | None = None, push_speed: float | None = None):
    """The scenario's env with fixed commands and the Table-4 reward: E episodes (one per row of ``cmds``)
    played ``replicas`` times side by side (robot s E + e: episode e). ``simple``: the base task on flat
    ground, no noise or perturbation. ``pushes``: the same with pushes of up to ``push_speed`` [m/s] per
    horizontal axis (``eval.pushes.pushes_task``; required there, refused elsewhere). ``survival`` /
    ``survival_sweep``: the eval suite's env of that
    scenario, every robot of episode e on the terrain tile and row the eval suite gives its env e, with the
    same scheduled disturbances (so a controller meets what the policy alone meets there). ``stairs``: the
    eval suite's staircase env (``eval.stairs.stairs_task``, one row per step height of ``heights``), episode
    e on row :func:`stairs_rows` (``cmds`` from :func:`commands` with the same heights). ``device``: the env's
    torch device; ``backend``: the simulator (``sim/interface.py``, e.g. ``cuda`` with ``device="cuda"``);
    ``overrides``: of the base task the scenario starts from (``eval.velocity_tracking.TaskEvalOptions``)."""
    import torch

    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.eval.velocity_tracking import TaskEvalOptions, flat_task

    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; allowed: {list(SCENARIOS)}")
    if (push_speed is None) == (scenario == "pushes"):
        raise ValueError(f"a push speed goes with the pushes scenario and only with it; got scenario {scenario!r} "
                         f"and push speed {push_speed!r}")
    e = len(cmds)
    tiled = np.tile(cmds, (replicas, 1))
    opts = TaskEvalOptions(episodes=len(tiled), seed=seed, num_workers=num_workers, episode_length_s=seconds,
                           task_overrides=overrides)
    if scenario == "simple":
        task = flat_task(tiled, opts)
    elif scenario == "pushes":
        from dls_quadruped.eval.pushes import pushes_task

        task = pushes_task(tiled, opts, push_speed)
    elif scenario == "stairs":
        from dls_quadruped.eval.stairs import stairs_task

        rows = stairs_rows(e, len(heights))  # before building the env: a bad episode count is a one-line error
        task = stairs_task(tiled, opts, tuple(heights))
    else:
        from dls_quadruped.eval import survival as SV

        task = SV.survival_task(tiled, opts, *_survival_layout(scenario))
    if backend != "cpu":
        task.data.setdefault("scene", {})["backend"] = backend
    env = LocomotionEnv(task, num_envs=len(tiled), device=device, seed=seed, verbose=False)
    if replicas > 1:
        env.reset(seed=seed, episode_keys=torch.arange(len(tiled)) % e)
    if scenario == "stairs":
        from dls_quadruped.eval.sweep import place_on_rows

        place_on_rows(env, rows[np.arange(len(tiled)) % e])
    elif scenario not in ("simple", "pushes"):
        from dls_quadruped.eval import survival as SV
        from dls_quadruped.eval.sweep import place_on_rows

        rows = _survival_layout(scenario)[0]
        place_on_rows(env, SV.start_rows(e, len(task.data["terrain"]["types"]), rows)[np.arange(len(tiled)) % e])
    return env


def terrain_of(env) -> dict:
    """Each robot's terrain type name, row (difficulty level) and start height (its tile origin's z [m]) in ``env``."""
    types = list(env.cfg["terrain"]["types"])
    col = env.scene.terrain_types.cpu().numpy()
    return {"types": types, "type": col.tolist(), "row": env.scene.terrain_levels.cpu().numpy().tolist(),
            "rows": int(env.scene.terrain.num_rows), "origin_z": env.scene.env_origins[:, 2].cpu().numpy().tolist()}


def run_controllers(configs: list[ControllerConfig], cmds: np.ndarray, seconds: float, seed: int,
                    num_workers: int, record_robots: int = 1, sampler_seeds: int = 1,
                    scenario: str = "simple", heights: tuple[float, ...] = STAIRS_HEIGHTS,
                    overrides: dict | None = None, push_speed: float | None = None, device: str = "cpu",
                    backend: str = "cpu") -> dict[str, ClosedLoopTraces]:
    """Each controller in a fresh env (same seed, scheduled episodes, ``scenario``; ``device`` and ``backend`` as in
    :func:`make_env`); traces by name. MPC
    controllers play every episode with ``sampler_seeds`` noise streams (``ClosedLoopTraces.replicas``);
    on a terrain scenario the traces carry each robot's terrain (``.terrain``, :func:`terrain_of`), on
    ``stairs`` with ``terrain["stairs"]`` = {"heights", "steps"} (the summary's per-height success); ``overrides``:
    of the base task, ``push_speed``: of the ``pushes`` scenario (:func:`make_env`)."""
    out = {}
    for cfg in configs:
        replicas = sampler_seeds if cfg.uses_mpc else 1
        env = make_env(cmds, seconds, seed, num_workers, replicas, scenario, heights, device=device, backend=backend,
                       overrides=overrides, push_speed=push_speed)
        try:
            terrain = terrain_of(env) if scenario not in ("simple", "pushes") else None
            if scenario == "stairs":
                from dls_quadruped.eval.stairs import steps_per_flight

                terrain["stairs"] = {"heights": [float(h) for h in heights], "steps": steps_per_flight()}
            controller = make_controller(cfg, env)
            out[cfg.name] = run_closed_loop(env, controller, record_robots=record_robots)
            out[cfg.name].replicas = replicas
            out[cfg.name].terrain = terrain
        finally:
            env.close()
    return out


def summarize_all(traces: dict[str, ClosedLoopTraces]) -> tuple[dict, dict]:
    """Per-controller summaries and the paired differences of every pair of controllers (same episodes)."""
    summaries = {name: summarize(tr, replicas=tr.replicas) for name, tr in traces.items()}
    names = list(summaries)
    paired = {f"{a} - {b}": compare(summaries[a], summaries[b]) for i, a in enumerate(names) for b in names[i + 1:]}
    return summaries, paired


def plot(traces: dict[str, ClosedLoopTraces], path: Path, robot: int = 0) -> None:
    """Velocity tracking of robot ``robot`` and the per-step costs, controllers side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(traces)
    fig, axes = plt.subplots(3, len(names), figsize=(4.2 * len(names), 8.5), squeeze=False, sharey="row")
    for c, name in enumerate(names):
        tr = traces[name]
        t = tr.time
        ax = axes[0, c]
        for i, (label, color) in enumerate((("v_x", "C0"), ("v_y", "C1"), ("omega_z", "C2"))):
            ax.plot(t, tr.base_vel[:, robot, i], color=color, lw=0.8, label=label)
            ax.axhline(tr.command[robot, i], color=color, ls="--", lw=0.8)
        ax.set_title(f"{name}\nrobot {robot}: measured (solid) vs command (dashed)", fontsize=9)
        ax.legend(fontsize=7, loc="lower right")
        ax = axes[1, c]
        ax.semilogy(t, tr.initial_cost[:, robot], lw=0.7, label="initial cost (state)")
        if np.isfinite(tr.rollout_cost).any():
            ax.semilogy(t, tr.rollout_cost[:, 0, robot], lw=0.7, label="rollout cost (chosen sample)")
        ax.set_title("cost per policy step, robot 0", fontsize=9)
        ax.legend(fontsize=7)
        ax = axes[2, c]
        ax.plot(t, np.nanmedian(tr.reward, axis=1), lw=0.8, label="RL reward, median over episodes")
        ax.set_xlabel("time [s]")
        ax.set_title(f"{tr.reward.shape[1]} episodes, survival {100 * (~tr.fell).mean():.0f} %", fontsize=9)
        ax.legend(fontsize=7)
    axes[0, 0].set_ylabel("velocity [m/s], [rad/s]")
    axes[1, 0].set_ylabel("cost")
    axes[2, 0].set_ylabel("reward per step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
