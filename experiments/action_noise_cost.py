"""What exploration noise on each latent-action component costs a trained policy (docs/train.md "Recipe").

PPO shrinks a Gaussian policy's std along a dimension only when noise there lowers the return; noise the
return does not feel leaves the std where it is. This measures that directly: the deterministic policy is run on
the simple task with Gaussian noise of std ``sigma`` (raw action units, as the training distribution's std) added to
one component's raw actions at every policy step -- f (4 step frequencies), d (4 duties), p (8 foothold offsets), F
(12 forces) or all 28 -- and its reward per step is paired with the noiseless policy's on the same episodes.

    python -m experiments.action_noise_cost --policy docs/policies/base_recipe_actor.pt2 --sigmas 0.5 1.0

Every condition draws the same (steps, robots, 28) noise sequence from one seeded generator and keeps only its
component's columns, so two conditions differ only in where the noise goes (common random numbers). Episodes: the
simple scenario's **validation** set (its test set stays for reports), 15 s, flat, the evaluation reward.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, positive_int, run_cli
from dls_quadruped.control.latent_action import ACTION_GROUPS

ROOT = Path(__file__).resolve().parents[1]

GROUPS = {**{name: rows for name, rows in ACTION_GROUPS}, "all": slice(0, 28)}
"""Component name -> columns of the 28-vector that get the noise."""


def noisy(policy, columns: slice, sigma: float, generator: torch.Generator):
    """``policy`` with N(0, sigma^2) added to ``columns`` of its raw actions at every call. The full (B, 28)
    draw is taken whatever the columns, so every condition consumes the generator alike."""

    mask = torch.zeros(28)
    mask[columns] = sigma  # the noise's std per column: sigma on the component, 0 elsewhere

    def act(obs):
        a = policy(obs)
        z = torch.randn(a.shape, generator=generator, dtype=a.dtype)
        return a + (z * mask.to(a.dtype)).to(a.device)

    return act


def run_condition(policy_path: Path, episodes: int, seed: int, group: str | None, sigma: float,
                  noise_seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(episodes,) reward per step of each episode and (episodes,) whether its robot fell; ``group`` None: the
    deterministic policy."""
    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.eval.policy import load_policy
    from dls_quadruped.eval.rollout import run_episodes
    from dls_quadruped.eval.scenario import EvalOptions
    from dls_quadruped.eval.velocity_tracking import (
        flat_task,
        simple_commands,
        summarize,
    )

    opts = EvalOptions(episodes=episodes, seed=seed, num_workers=0)
    cmd = simple_commands(episodes, seed)
    env = LocomotionEnv(flat_task(cmd, opts), num_envs=episodes, device="cpu", seed=seed, verbose=False)
    try:
        torch.manual_seed(seed)
        policy = load_policy(policy_path, env)
        if group is not None:
            policy = noisy(policy, GROUPS[group], sigma, torch.Generator().manual_seed(noise_seed))
        traces = run_episodes(env, policy)
    finally:
        env.close()
    return np.asarray(summarize(traces)["per_episode"]["reward"], dtype=float), traces.fell.astype(bool)


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", type=Path, default=ROOT / "docs" / "policies" / "base_recipe_actor.pt2")
    p.add_argument("--sigmas", type=float, nargs="+", default=[0.5, 1.0], help="noise std, raw action units")
    p.add_argument("--groups", nargs="+", default=list(GROUPS), choices=list(GROUPS))
    p.add_argument("--episodes", type=positive_int, default=64)
    p.add_argument("--seed", type=int, default=0, help="scenario seed (the validation split of it is used)")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "train" / "action_noise_cost")
    a = p.parse_args(argv)
    if any(s <= 0 for s in a.sigmas):
        p.error(f"argument --sigmas: every noise std must be > 0, got {a.sigmas}")
    if a.episodes % 2:
        p.error(f"argument --episodes: the simple task pairs each command with its mirror, give an even number, "
                f"got {a.episodes}")
    if not a.policy.is_file():
        p.error(f"argument --policy: {a.policy} not found")
    from dls_quadruped.eval.metrics import paired_difference
    from dls_quadruped.eval.scenario import split_seed

    seed = split_seed(a.seed, "validation")
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    base, base_fell = run_condition(a.policy, a.episodes, seed, None, 0.0, 0)
    print(f"[noise] none: reward per step {base.mean():.4f}, {base_fell.sum()} fell", flush=True)
    rows = []
    for sigma in a.sigmas:
        for group in a.groups:
            r, fell = run_condition(a.policy, a.episodes, seed, group, sigma, noise_seed=1000 + a.seed)
            d = paired_difference(r, base)
            rows.append({"group": group, "sigma": sigma, "dims": len(range(28)[GROUPS[group]]),
                         "reward_per_step": float(r.mean()), "minus_none": d["mean"], "ci95": d["ci95"],
                         "fell": int(fell.sum())})
            print(f"[noise] {group} sigma {sigma}: {r.mean():.4f}, minus none {d['mean']:+.4f} "
                  f"[{d['ci95'][0]:+.4f}, {d['ci95'][1]:+.4f}], {rows[-1]['fell']} fell", flush=True)
    shown = a.policy.resolve().relative_to(ROOT) if a.policy.resolve().is_relative_to(ROOT) else a.policy
    res = {"policy": str(shown), "episodes": a.episodes, "scenario": "simple", "split": "validation",
           "scenario_seed": seed, "none": {"reward_per_step": float(base.mean()), "fell": int(base_fell.sum())},
           "rows": rows, "seconds": round(time.monotonic() - t0, 1)}
    (a.out / "results.json").write_text(json.dumps(res, indent=1) + "\n")
    lines = [(f"Noise on one component of `{a.policy.name}`'s raw actions, simple task, {a.episodes} validation "
              f"episodes; reward per step without noise {base.mean():.3f}."), "",
             "| component (dims) | noise std | reward per step | minus no noise [95 %] | episodes with a fall |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['group']} ({r['dims']}) | {r['sigma']} | {r['reward_per_step']:.3f} | "
                     f"{r['minus_none']:+.3f} [{r['ci95'][0]:+.3f}, {r['ci95'][1]:+.3f}] | {r['fell']} |")
    (a.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return res


if __name__ == "__main__":
    run_cli(main)
