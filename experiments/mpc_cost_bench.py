"""What the ``mpc_trajectory_cost`` reward term costs per env step, on the CPU.

``base_mpc_cost`` at N robots, in-process (no simulator workers), one torch thread, a fixed action (the DAgger
student's horizon at the reset observation, so the rollout scores a real horizon): rounds alternate the task as it
is and the task with the term's weight 0 (the reward manager skips a term of weight 0), each round ``--steps`` env
steps after 5 warm-up steps; the term's share is (with - without) / without, median over rounds. The term's own
call (``rewards.mpc_trajectory_cost`` with the task's parameters: the kernel's cost every step, the split by term
every ``split_every``-th) and the split alone (``mpc.horizon.score_horizon(..., terms=True)``) are timed beside it.

    python -m experiments.mpc_cost_bench --num-envs 256 --rounds 3 --steps 40
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp import rewards
from dls_quadruped.learning.student import load_student
from dls_quadruped.mpc import horizon as mpc_horizon

STUDENT = Path("docs/policies/base_recipe_student_first_spline_h10.pt2")


def _env(num_envs: int, weight: float | None) -> LocomotionEnv:
    overrides: dict = {"scene": {"num_workers": 0}}
    if weight is not None:
        overrides["rewards"] = {"mpc_trajectory_cost": {"weight": weight}}
    return LocomotionEnv(load_task("base_mpc_cost", overrides=overrides), num_envs=num_envs, verbose=False, seed=0)


def _ms_per_step(env: LocomotionEnv, action: torch.Tensor, steps: int) -> float:
    tic = time.perf_counter()
    for _ in range(steps):
        env.step(action)
    return 1e3 * (time.perf_counter() - tic) / steps


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--num-envs", type=int, default=256)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, default=Path("results/bench/mpc_cost.json"))
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    envs = {"with": _env(args.num_envs, None), "without": _env(args.num_envs, 0.0)}
    student, _ = load_student(STUDENT)
    obs, _ = envs["with"].reset()
    envs["without"].reset()
    with torch.no_grad():
        action = student(obs["policy"])
    times: dict[str, list[float]] = {"with": [], "without": [], "term": [], "with_split": []}
    try:
        for env in envs.values():
            _ms_per_step(env, action, 5)
        env = envs["with"]
        am = env.action_manager
        cfg = mpc_horizon.horizon_sampler_config(am.horizon, am.horizon_dt, am.cfg)
        (term,) = [t for t in env.reward_manager.terms if t.name == "mpc_trajectory_cost"]
        for _ in range(args.rounds):
            for name, e in envs.items():
                times[name].append(_ms_per_step(e, action, args.steps))
            tic = time.perf_counter()
            for _ in range(args.steps):
                rewards.mpc_trajectory_cost(env, **term.params)
            times["term"].append(1e3 * (time.perf_counter() - tic) / args.steps)
            tic = time.perf_counter()
            for _ in range(args.steps):
                mpc_horizon.score_horizon(am.raw_horizon, am.decision_state, am.decision_command, 0.404, cfg,
                                          terms=True)
            times["with_split"].append(1e3 * (time.perf_counter() - tic) / args.steps)
    finally:
        for env in envs.values():
            env.close()
    med = {k: statistics.median(v) for k, v in times.items()}
    result = {"num_envs": args.num_envs, "threads": args.threads, "rounds": args.rounds, "steps": args.steps,
              "ms_per_env_step": times, "median_ms": med,
              "share_of_env_step": (med["with"] - med["without"]) / med["without"],
              "term_call_share": med["term"] / med["without"], "split_call_share": med["with_split"] / med["without"]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(result, args.out)
    print(f"N = {args.num_envs}: env step {med['without']:.1f} ms without the term, {med['with']:.1f} ms with it "
          f"(+{100 * result['share_of_env_step']:.1f} %); the term's call {med['term']:.2f} ms "
          f"({100 * result['term_call_share']:.1f} % of an env step), with the split every call "
          f"{med['with_split']:.2f} "
          f"ms ({100 * result['split_call_share']:.1f} %); {args.out}")
    return result


if __name__ == "__main__":
    run_cli(main)
