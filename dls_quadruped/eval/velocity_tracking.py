"""Velocity-tracking scenarios on flat ground: the thesis's *simple task* (7.1.2) and a fixed forward command.

``simple``: one command per 15 s episode, v_x ~ U[0.3, 0.6] m/s, v_y ~ U[-0.2, 0.2] m/s,
omega_z ~ U[-0.5, 0.5] rad/s; the second half of the episodes replays the first half's commands
mirrored (v_y and omega_z negated), which keeps the distribution and pairs every episode with its
mirror image. The env is the base task (flat, no observation noise, no perturbation, its
terminations) with the evaluation reward (Table 4, base column). Reported:

* survival: episodes that reach the time-out, with a 95 % Wilson interval;
* per axis (v_x, v_y, omega_z), from each episode's mean velocity after a 2 s settle: the slope of
  achieved on commanded (least squares) and the mean signed error achieved - commanded;
* median and quartiles over episodes of the mean |v_xy - cmd_xy| [m/s] and |omega_z - cmd| [rad/s]
  after the settle;
* mirror comparison: per pair, the episode's mean velocity minus the mirror image of its mirrored
  episode's; mean |difference| and mean difference per axis (0 for a left-right symmetric policy
  on a symmetric robot; the AlienGo trunk's 4 mm lateral COM offset is the only asymmetry);
* the per-step reward of the evaluation reward without the dt factor (the "RL Reward" of 7.3;
  thesis RL baseline 2.365), over every step of every episode until it ends.

``forward``: every episode commanded (0.5, 0, 0) m/s, rad/s (what ``bench/tracking.py`` measured).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.envs.config import (
    TOP_LEVEL_KEYS,
    ConfigError,
    load_task,
    merge_overrides,
)
from dls_quadruped.eval import metrics as M
from dls_quadruped.eval.rollout import Traces, run_episodes
from dls_quadruped.eval.scenario import (
    EvalOptions,
    Scenario,
    eval_rewards,
    replace_sections,
)

SIMPLE_RANGES = ((0.3, 0.6), (-0.2, 0.2), (-0.5, 0.5))
"""Simple task (7.1.2): (low, high) of v_x [m/s], v_y [m/s], omega_z [rad/s]."""
SETTLE_S = 2.0
"""[s] start-up transient excluded from the tracking metrics."""
MIRROR = np.array([1.0, -1.0, -1.0])
"""Mirror image of a (v_x, v_y, omega_z) command or velocity."""
AXES = ("v_x", "v_y", "omega_z")
THESIS_RL_REWARD = 2.365
"""Per-step base-task reward of the thesis's RL baseline (Table 14)."""

TARGETS = {
    # the simple task's acceptance bounds; name: (metric path in the results, "min"/"max", bound)
    "survival": ("survival.rate", "min", 1.0),
    **{f"slope_{a}": (f"axes.{a}.slope", "min", 0.9) for a in AXES},
    **{f"abs_mean_error_{a}": (f"axes.{a}.abs_mean_error", "max", 0.03) for a in AXES},
    "median_vxy_error": ("tracking.vxy_error.median", "max", 0.06),
    **{f"mirror_{a}": (f"mirror.{a}.mean_abs_diff", "max", 0.03) for a in AXES},
    "reward_per_step": ("reward.per_step", "min", 2.30),
}


# ------------------------------------------------------------------ commands
def mirrored_pairs(first: np.ndarray) -> np.ndarray:
    """(P, 3) commands -> (2 P, 3): the commands, then their mirror images."""
    return np.concatenate([first, first * MIRROR], axis=0)


def simple_commands(episodes: int, seed: int) -> np.ndarray:
    """(episodes, 3) simple-task commands in mirrored pairs (``episodes`` must be even)."""
    if episodes < 2 or episodes % 2:
        raise ValueError(f"the simple task pairs each command with its mirror: episodes must be even and >= 2, got "
                         f"{episodes}")
    rng = np.random.default_rng(seed)
    lo, hi = np.array(SIMPLE_RANGES).T
    return mirrored_pairs(rng.uniform(lo, hi, size=(episodes // 2, 3)))


def forward_commands(episodes: int, seed: int) -> np.ndarray:
    """(episodes, 3) all (0.5, 0, 0)."""
    if episodes < 2 or episodes % 2:
        raise ValueError(f"episodes must be even and >= 2, got {episodes}")
    return mirrored_pairs(np.tile([0.5, 0.0, 0.0], (episodes // 2, 1)))


# ------------------------------------------------------------------ env
FIXED_SECTIONS = ("terrain", "observations", "events", "commands", "rewards", "curriculum")
"""Sections of the task that every evaluation env (``flat_task`` and the scenarios built on it) sets itself."""
OVERRIDABLE_SECTIONS = tuple(k for k in TOP_LEVEL_KEYS if k not in FIXED_SECTIONS)
"""Sections a task override (``--set``) of an evaluation env can change."""


@dataclass(frozen=True)
class TaskEvalOptions(EvalOptions):
    """``EvalOptions`` with overrides of the task the evaluation env starts from.

    Attributes:
        task_overrides: nested dict (``cli.set_overrides``) deep-merged onto the task after ``num_workers`` and
            ``episode_length_s``, within ``OVERRIDABLE_SECTIONS``; None: none.
    """

    task_overrides: dict | None = None


def flat_task(commands: np.ndarray, opts: EvalOptions, task: str = "base"):
    """``task`` on flat ground, without observation noise or perturbation events, with one fixed
    command per env for the whole episode, the evaluation reward and no curriculum.

    ``opts.task_overrides`` (a ``TaskEvalOptions``) apply to ``task`` first; one touching a section the
    evaluation env sets itself (``FIXED_SECTIONS``) would be silently replaced and is refused.

    Raises:
        ConfigError: an override of a fixed section, or one the task file's checks refuse.
    """
    extra = getattr(opts, "task_overrides", None) or {}
    fixed = sorted(set(extra) & set(FIXED_SECTIONS))
    if fixed:
        raise ConfigError(f"<override>: {fixed}: the evaluation env sets these sections itself; an override can "
                          f"change {list(OVERRIDABLE_SECTIONS)}")
    cfg = load_task(task, overrides=merge_overrides({"scene": {"num_workers": opts.num_workers},
                                                     "env": {} if opts.episode_length_s is None
                                                     else {"episode_length_s": float(opts.episode_length_s)}}, extra))
    episode_s = float(cfg.data["env"]["episode_length_s"])
    observations = {g: {**spec, "noise_scale": 0.0} for g, spec in cfg.data["observations"].items()}
    reset = {k: v for k, v in cfg.data["events"].items() if k == "reset_robot"}
    reset["reset_robot"] = {**reset.get("reset_robot", {"mode": "reset"}), "params": {"joint_scale": [1.0, 1.0]}}
    never = [10.0 * episode_s, 10.0 * episode_s]  # no resampling within an episode
    return replace_sections(cfg, {
        "terrain": {"types": ["flat"]},
        "observations": observations,
        "events": reset,
        "commands": {"base_velocity": {"func": "fixed_velocity", "resampling_time_s": never,
                                       "params": {"values": np.asarray(commands, dtype=float).tolist()}}},
        "rewards": eval_rewards(),
        "curriculum": {},
    }, source="<eval: flat, fixed commands, Table-4 reward>")


# ------------------------------------------------------------------ metrics
def _get(results: dict, dotted: str):
    for key in dotted.split("."):
        results = results[key]
    return results


def check_targets(results: dict, targets: dict = TARGETS) -> dict:
    """{name: {value, bound, kind, met}} for every target."""
    out = {}
    for name, (path, kind, bound) in targets.items():
        value = float(_get(results, path))
        met = bool(value >= bound) if kind == "min" else bool(value <= bound)
        out[name] = {"value": value, "kind": kind, "bound": bound, "met": bool(met and np.isfinite(value))}
    return out


def summarize(traces: Traces, settle_s: float = SETTLE_S, pairs: np.ndarray | None = None) -> dict:
    """Metrics of one batch of episodes (see the module docstring).

    Args:
        traces: from ``run_episodes``.
        settle_s: [s] start-up excluded from the velocity metrics.
        pairs: (P, 2) episode indices (i, j) with command j the mirror image of command i; None: none.
    """
    cmd = traces.command.astype(float)                          # (E, 3)
    vel = traces.velocity.astype(float)                         # (T, E, 3)
    steps, episodes = traces.valid.shape
    settle = round(settle_s / traces.step_dt)
    settled = traces.valid & (np.arange(steps)[:, None] >= settle)  # (T, E)
    mean_vel = M.masked_mean(vel, settled)                      # (E, 3) per-episode mean after the settle
    err_xy = np.linalg.norm(vel[..., :2] - cmd[None, :, :2], axis=-1)  # (T, E) |v_xy - cmd_xy|
    err_yaw = np.abs(vel[..., 2] - cmd[None, :, 2])             # (T, E) |omega_z - cmd|
    survived = int((~traces.fell).sum())
    lo, hi = M.wilson_interval(survived, episodes)
    res: dict = {
        "episodes": episodes,
        "settle_s": settle_s,
        "episode_steps": steps,
        "survival": {"rate": survived / episodes, "ci95": [lo, hi], "survived": survived, "n": episodes,
                     "mean_length_s": float(traces.length.mean() * traces.step_dt)},
        "axes": {},
        "tracking": {"vxy_error": M.median_iqr(M.masked_mean(err_xy, settled)),
                     "yaw_rate_error": M.median_iqr(M.masked_mean(err_yaw, settled))},
    }
    for a, name in enumerate(AXES):
        fit = M.linear_fit(cmd[:, a], mean_vel[:, a])
        err = M.mean_ci(mean_vel[:, a] - cmd[:, a])
        res["axes"][name] = {"slope": fit["slope"], "slope_ci95": fit["slope_ci95"], "intercept": fit["intercept"],
                             "mean_error": err["mean"], "mean_error_ci95": err["ci95"],
                             "abs_mean_error": abs(err["mean"]), "n": err["n"]}
    if pairs is not None and len(pairs):
        diff = mean_vel[pairs[:, 0]] - mean_vel[pairs[:, 1]] * MIRROR  # (P, 3)
        res["mirror"] = {name: {"mean_abs_diff": M.mean_ci(np.abs(diff[:, a]))["mean"],
                                "mean_abs_diff_ci95": M.mean_ci(np.abs(diff[:, a]))["ci95"],
                                "mean_diff": M.mean_ci(diff[:, a])["mean"],
                                "mean_diff_ci95": M.mean_ci(diff[:, a])["ci95"], "n": M.mean_ci(diff[:, a])["n"]}
                         for a, name in enumerate(AXES)}
    per_episode_reward = np.nanmean(traces.reward, axis=0)      # (E,) mean per-step reward of each episode
    res["reward"] = {"per_step": float(np.nanmean(traces.reward)),  # pooled over every step of every episode
                     "per_episode": M.mean_ci(per_episode_reward),
                     "per_episode_quartiles": M.median_iqr(per_episode_reward),
                     "thesis_rl_baseline": THESIS_RL_REWARD,
                     "terms": "Table 4 base column (tasks/_base_rewards.yaml), weights per second, no dt"}
    res["per_episode"] = {"command": cmd.round(5).tolist(), "mean_velocity": np.round(mean_vel, 5).tolist(),
                          "fell": traces.fell.astype(bool).tolist(),
                          "length_s": (traces.length * traces.step_dt).round(3).tolist(),
                          "reward": np.round(per_episode_reward, 5).tolist()}
    return res


def paired_indices(episodes: int) -> np.ndarray:
    """(E/2, 2) pairs (i, i + E/2): the layout of ``mirrored_pairs``."""
    half = episodes // 2
    return np.stack([np.arange(half), np.arange(half) + half], axis=1)


# ------------------------------------------------------------------ scenario
def velocity_scenario(name: str, description: str, commands: Callable[[int, int], np.ndarray],
                      ranges: tuple | None = None, targets: dict | None = None) -> Scenario:
    """A flat-ground velocity-tracking scenario with the given command generator; ``targets``
    (like ``TARGETS``) are checked in the results when given."""

    def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
        from dls_quadruped.envs.env import LocomotionEnv
        from dls_quadruped.eval.policy import load_policy

        cmd = commands(opts.episodes, opts.seed)
        env = LocomotionEnv(flat_task(cmd, opts), num_envs=opts.episodes, device=opts.device, seed=opts.seed,
                            verbose=False)
        try:
            torch.manual_seed(opts.seed)
            traces = run_episodes(env, load_policy(policy_path, env))
        finally:
            env.close()
        res = {"scenario": name, "description": description, "policy": str(policy_path),
               "command_ranges": ranges, "seed": opts.seed, "episode_length_s": traces.valid.shape[0] * traces.step_dt,
               **summarize(traces, SETTLE_S, paired_indices(opts.episodes))}
        if targets:
            res["targets"] = check_targets(res, targets)
        return res

    return Scenario(name, description, evaluate, plot_tracking, episodes_multiple=2)


def plot_tracking(results: dict, path: Path) -> None:
    """Commanded vs achieved (per-episode mean after the settle), one panel per axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = results["per_episode"]
    cmd, vel, fell = np.array(ep["command"]), np.array(ep["mean_velocity"]), np.array(ep["fell"])
    half = len(cmd) // 2
    mirrored = np.arange(len(cmd)) >= half
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2))
    units = ("m/s", "m/s", "rad/s")
    for a, (ax, name) in enumerate(zip(axes, AXES)):
        seen = np.concatenate([cmd[:, a], vel[np.isfinite(vel[:, a]), a]])
        lim = [seen.min() - 0.05, seen.max() + 0.05]
        ax.plot(lim, lim, color="0.6", lw=1, label="achieved = commanded")
        ax.scatter(cmd[~mirrored, a], vel[~mirrored, a], s=10, label="commands")
        ax.scatter(cmd[mirrored, a], vel[mirrored, a], s=10, marker="^", label="mirrored commands")
        if fell.any():
            ax.scatter(cmd[fell, a], vel[fell, a], s=30, marker="x", color="red", label="fell")
        r = results["axes"][name]
        ax.set_title(f"{name}: slope {r['slope']:.2f}, mean error {r['mean_error']:+.3f}")
        ax.set_xlabel(f"commanded {name} [{units[a]}]")
        ax.set_ylabel(f"achieved {name} [{units[a]}] (mean after {results['settle_s']:g} s)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    s = results["survival"]
    fig.suptitle(f"{results['scenario']}: {Path(results['policy']).name}, {results['episodes']} episodes, "
                 f"survival {100 * s['rate']:.1f} %, reward/step {results['reward']['per_step']:.3f}", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


SCENARIOS = (
    velocity_scenario("simple", "thesis 7.1.2 simple task: one command per episode, flat, no disturbance",
                      simple_commands, SIMPLE_RANGES, TARGETS),
    # identical commands: no slope; the mirror difference of v_y and omega_z is twice the drift
    velocity_scenario("forward", "fixed forward command (0.5 m/s, 0, 0), flat, no disturbance", forward_commands),
)
"""The scenarios of this module, for ``scenarios.SCENARIOS``."""
