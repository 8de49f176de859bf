"""Cost of the gymnasium view: steps/s of ``LocomotionVectorEnv.step`` beside ``LocomotionEnv.step``.

Both step the *same* env (the view is built over it), in alternating rounds so that a change of the
machine's load hits both alike, with random actions that make robots fall, so that most steps reset
some robot; with ``--final-obs all`` the view then computes ``info["final_obs"]`` on (nearly) every
step (one more observation pass), with the default ``truncated`` only on time-out steps.
Reports the median steps/s of each and the view's overhead ``1 - view / native``.

    python -m dls_quadruped.bench.gym_env [--task rough] [--num-envs 1024] [--rounds 5] [--steps 10]

Writes ``<out>/gym_env_<final-obs mode>.json``.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, positive_int, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.core.progress import progress
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.gym_env import LocomotionVectorEnv


def measure(task: str, num_envs: int, rounds: int, steps: int, num_workers: int | None,
            final_obs: str = "truncated") -> dict:
    """Median RL steps/s (robot steps per second) of the native env and of the gymnasium view over it."""
    overrides = None if num_workers is None else {"scene": {"num_workers": num_workers}}
    env = LocomotionEnv(load_task(task, overrides=overrides), num_envs=num_envs, verbose=False)
    view = LocomotionVectorEnv(env=env, final_obs=final_obs)
    gen = torch.Generator().manual_seed(0)
    rates: dict[str, list[float]] = {"native": [], "gymnasium": []}
    resets = 0
    try:
        steppers = {"native": env.step, "gymnasium": view.step}
        for stepper in steppers.values():  # warm-up
            stepper(torch.randn(num_envs, 28, generator=gen))
        for _ in progress(range(rounds), desc=f"{task} N={num_envs} rounds", unit="round"):
            for name, stepper in steppers.items():
                actions = [3.0 * torch.randn(num_envs, 28, generator=gen) for _ in range(steps)]
                t0 = time.perf_counter()
                for a in actions:
                    out = stepper(a)
                    if name == "gymnasium":
                        resets += int(bool(out[2].any() or out[3].any()))
                rates[name].append(num_envs * steps / (time.perf_counter() - t0))
    finally:
        view.close()
    native, gym = statistics.median(rates["native"]), statistics.median(rates["gymnasium"])
    return {"task": task, "final_obs": final_obs, "num_envs": num_envs, "workers": env.scene.sim.num_workers,
            "rounds": rounds,
            "steps": steps, "native_steps_per_s": native, "gymnasium_steps_per_s": gym,
            "overhead": 1.0 - gym / native, "view_steps_with_a_reset": resets / (rounds * steps), "rates": rates}


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="rough")
    parser.add_argument("--num-envs", type=positive_int, default=1024)
    parser.add_argument("--rounds", type=positive_int, default=5, help="alternating rounds (median reported)")
    parser.add_argument("--steps", type=positive_int, default=10, help="RL steps per round")
    parser.add_argument("--num-workers", type=int, default=None, help="simulator processes (default: the task's)")
    parser.add_argument("--final-obs", choices=("truncated", "all", "none"), default="truncated",
                        help="the view's final_obs mode (default truncated)")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    res = {"cpu": cpu_model(), "torch": torch.__version__, "load_avg_before": load_before,
           **measure(args.task, args.num_envs, args.rounds, args.steps, args.num_workers, args.final_obs),
           "load_avg_after": os.getloadavg()}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(res, args.out / f"gym_env_{args.final_obs}.json", indent=1)
    print(f"[bench.gym_env] {res['task']} N={res['num_envs']} final_obs={res['final_obs']}: native "
          f"{res['native_steps_per_s']:,.0f} steps/s, "
          f"gymnasium view {res['gymnasium_steps_per_s']:,.0f} steps/s, overhead {100 * res['overhead']:+.1f} % "
          f"({100 * res['view_steps_with_a_reset']:.0f} % of the view's steps reset a robot)")
    return res


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
