"""RL environment benchmark (``make bench``, env part).

Measures, for the ``base`` task (flat ground) and the ``rough`` task at each N:

* ``env_steps_per_s``: RL steps per second of the full ``LocomotionEnv.step`` (managers, height
  scan, latent action -> low-level control, 4 physics steps) with the untrained policy's actions
  (Gaussian, std 1, i.e. random actions), after warm-up; backend in worker processes (one per core);
* ``stage_share``: share of the env step + policy time per stage, from ``time.perf_counter``
  wrappers around the env's own calls: ``backend`` (``VecSim.step``: physics + Pinocchio +
  low-level control), ``action`` (latent action -> references), ``termination``, ``reward``,
  ``reset`` (curriculum, reset events, manager resets), ``observation`` (incl. height scan),
  ``other`` (command resampling, interval events, bookkeeping) and ``policy`` (actor + critic
  forward, ``PPO.act``);
* ``backend_split``: the backend's own split into physics / Pinocchio / control, measured on an
  in-process shard (``num_workers=0``, same N) by wrapping ``Shard._dynamics_terms`` (Pinocchio)
  and ``LowLevelController.compute`` (control); physics = the rest of ``Shard.step``;
* one PPO iteration (rsl-rl-lib's ``PPO`` from the task's agent config, 24 steps per env) split
  into collection (env + policy + storage) and learning (returns + 5 epochs x 4 mini-batches).

Writes ``results/bench/rl_env.json`` (with the machine and its load, ``os.getloadavg``) and prints
the markdown tables of ``docs/benchmarks.md``. Usage::

    python -m dls_quadruped.bench.rl_env [--sizes 1024 4096] [--ppo-size 4096] [--threads 1] [--quick]
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import torch
from rsl_rl.runners import OnPolicyRunner

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.progress import progress
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning.runner import runner_config

TASKS = ("base", "rough")
ENV_STAGES = ("backend", "action", "termination", "reward", "reset", "observation")


class StageTimer:
    """Accumulates wall time [s] per stage name; ``wrap`` instruments a bound method in place."""

    def __init__(self) -> None:
        self.total: dict[str, float] = defaultdict(float)
        self.enabled = True

    def wrap(self, obj: Any, method: str, stage: str) -> None:
        """Replace ``obj.method`` by a timed call (an instance attribute shadowing the method)."""
        fn: Callable = getattr(obj, method)

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                if self.enabled:
                    self.total[stage] += time.perf_counter() - t0

        setattr(obj, method, timed)

    def reset(self) -> None:
        self.total.clear()


def instrument_env(env: LocomotionEnv, timer: StageTimer) -> None:
    """Time the top-level calls of ``LocomotionEnv.step`` (see its docstring for the order)."""
    timer.wrap(env.scene.sim, "step", "backend")
    timer.wrap(env.action_manager, "process", "action")
    timer.wrap(env.termination_manager, "compute", "termination")
    timer.wrap(env.reward_manager, "compute", "reward")
    timer.wrap(env, "_reset", "reset")
    timer.wrap(env.observation_manager, "compute", "observation")


def make_runner(env: LocomotionEnv, task_data: dict) -> OnPolicyRunner:
    """rsl-rl-lib runner (no log dir: nothing is written) with the task's agent config."""
    return OnPolicyRunner(env, runner_config(task_data["agent"], seed=0), log_dir=None, device="cpu")


def env_throughput(env: LocomotionEnv, runner: OnPolicyRunner, timer: StageTimer, steps: int,
                   warmup: int) -> dict[str, Any]:
    """RL steps/s of ``env.step`` with the policy's (random) actions, and the time share per stage."""
    alg = runner.alg
    obs = env.get_observations()
    with torch.inference_mode():
        for _ in range(warmup):
            obs, *_ = env.step(alg.act(obs))
        alg.storage.clear()
        timer.reset()
        t_env = 0.0
        t0 = time.perf_counter()
        for _ in range(steps):
            ta = time.perf_counter()
            actions = alg.act(obs)
            tb = time.perf_counter()
            timer.total["policy"] += tb - ta
            obs, *_ = env.step(actions)
            t_env += time.perf_counter() - tb
        wall = time.perf_counter() - t0
        alg.storage.clear()
    stages = {k: timer.total.get(k, 0.0) for k in ENV_STAGES}
    stages["other"] = max(t_env - sum(stages.values()), 0.0)
    stages["policy"] = timer.total["policy"]
    return {
        "env_steps_per_s": env.num_envs * steps / t_env,
        "env_plus_policy_steps_per_s": env.num_envs * steps / wall,
        "seconds_per_env_step": t_env / steps,
        "stage_seconds": stages,
        "stage_share": {k: v / wall for k, v in stages.items()},
    }


def backend_split(task: str, n: int, steps: int) -> dict[str, float]:
    """Physics / Pinocchio / control shares of ``VecSim.step`` on an in-process shard (num_workers=0)."""
    cfg = load_task(task, overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(cfg, num_envs=n, verbose=False)
    try:
        shard = env.scene.sim.in_process_shard
        timer = StageTimer()
        timer.wrap(shard, "_dynamics_terms", "pinocchio")
        timer.wrap(shard.controller, "compute", "control")
        timer.wrap(shard, "step", "backend")
        actions = torch.randn(steps + 2, n, env.num_actions)
        for a in actions[:2]:  # warm-up
            env.step(a)
        timer.reset()
        for a in actions[2:]:
            env.step(a)
        total = timer.total["backend"]
        physics = max(total - timer.total["pinocchio"] - timer.total["control"], 0.0)
        return {"physics": physics / total, "pinocchio": timer.total["pinocchio"] / total,
                "control": timer.total["control"] / total, "inprocess_backend_seconds_per_step": total / steps}
    finally:
        env.close()


def ppo_iteration(env: LocomotionEnv, runner: OnPolicyRunner) -> dict[str, float]:
    """One PPO iteration as in ``OnPolicyRunner.learn``: collection, then returns + update."""
    alg, n_steps = runner.alg, int(runner.cfg["num_steps_per_env"])
    alg.train_mode()
    obs = env.get_observations()
    t0 = time.perf_counter()
    with torch.inference_mode():
        for _ in range(n_steps):
            actions = alg.act(obs)
            obs, rewards, dones, extras = env.step(actions)
            alg.process_env_step(obs, rewards, dones, extras)
        t1 = time.perf_counter()
        alg.compute_returns(obs)
    alg.update()
    t2 = time.perf_counter()
    return {"num_envs": env.num_envs, "steps_per_env": n_steps, "collection_s": t1 - t0, "learning_s": t2 - t1,
            "total_s": t2 - t0, "samples": env.num_envs * n_steps}


def machine_info() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "torch": torch.__version__,
            "torch_threads": torch.get_num_threads(), "mujoco": mujoco.__version__}


def run(tasks: list[str], sizes: list[int], ppo_size: int | None, ppo_task: str, steps: int, warmup: int,
        split_size: int | None) -> dict[str, Any]:
    rows, ppo = [], None
    bar = progress(total=len(tasks) * len(sizes), desc="task x robot count", unit="config")
    for task in tasks:
        for n in sizes:
            cfg = load_task(task)
            env = LocomotionEnv(cfg, num_envs=n, verbose=False)
            try:
                runner = make_runner(env, cfg.data)
                timer = StageTimer()
                instrument_env(env, timer)
                load0 = os.getloadavg()[0]
                row = {"task": task, "num_envs": n, "steps": steps, "workers": env.scene.sim.num_workers,
                       **env_throughput(env, runner, timer, steps, warmup), "load_1min": [load0, os.getloadavg()[0]]}
                print(f"[bench.rl_env] {task} N={n}: {row['env_steps_per_s']:,.0f} env steps/s, "
                      f"{row['env_plus_policy_steps_per_s']:,.0f} with policy; shares "
                      + ", ".join(f"{k} {v:.0%}" for k, v in row["stage_share"].items()), flush=True)
                if ppo_size == n and task == ppo_task:
                    timer.enabled = False
                    ppo = {"task": task, **ppo_iteration(env, runner), "load_1min": os.getloadavg()[0]}
                    print(f"[bench.rl_env] PPO iteration {task} {n} x {ppo['steps_per_env']}: collection "
                          f"{ppo['collection_s']:.1f} s + learning {ppo['learning_s']:.1f} s = {ppo['total_s']:.1f} s",
                          flush=True)
                rows.append(row)
            finally:
                env.close()
            bar.update(1)
    bar.close()
    splits = {}
    if split_size:
        for task in tasks:
            splits[task] = backend_split(task, split_size, max(steps // 2, 2))
            print(f"[bench.rl_env] backend split {task} N={split_size} (in-process): "
                  + ", ".join(f"{k} {v:.2f}" for k, v in splits[task].items()), flush=True)
    return {"rows": rows, "ppo_iteration": ppo, "backend_split": {"num_envs": split_size, "tasks": splits}}


def markdown(result: dict[str, Any]) -> str:
    stages = (*ENV_STAGES, "other", "policy")
    lines = ["| task | N | env steps/s | env + policy steps/s | " + " | ".join(stages) + " |",
             "|---|---|---|---|" + "---|" * len(stages)]
    for r in result["rows"]:
        lines.append(f"| {r['task']} | {r['num_envs']} | {r['env_steps_per_s']:,.0f} | "
                     f"{r['env_plus_policy_steps_per_s']:,.0f} | "
                     + " | ".join(f"{r['stage_share'][s]:.0%}" for s in stages) + " |")
    split = result["backend_split"]
    if split["tasks"]:
        lines += ["", f"Backend split (in-process shard, N = {split['num_envs']}):", "",
                  "| task | physics | Pinocchio | control |", "|---|---|---|---|"]
        for task, s in split["tasks"].items():
            lines.append(f"| {task} | {s['physics']:.0%} | {s['pinocchio']:.0%} | {s['control']:.0%} |")
    p = result["ppo_iteration"]
    if p:
        lines += ["", (f"PPO iteration ({p['task']}, {p['num_envs']} envs x {p['steps_per_env']} steps = "
                       f"{p['samples']:,} samples): collection {p['collection_s']:.1f} s, "
                       f"learning {p['learning_s']:.1f} s, total {p['total_s']:.1f} s.")]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--ppo-size", type=int, default=4096, help="N of the PPO iteration (0: skip)")
    parser.add_argument("--ppo-task", default="rough")
    parser.add_argument("--split-size", type=int, default=1024, help="N of the backend split (0: skip)")
    parser.add_argument("--steps", type=int, default=10, help="measured RL steps per configuration")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="N = 256, 4 steps, PPO at 256 (a smoke run)")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch intra-op threads of the main process (0: torch's default); 1 is far faster "
                             "than 2 when the 2 cores are shared (OpenMP threads wait on each other)")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.quick:
        args.sizes, args.ppo_size, args.split_size, args.steps, args.warmup = [256], 256, 256, 4, 1
    t0 = time.perf_counter()
    uptime = Path("/proc/uptime").read_text().split()[0] if Path("/proc/uptime").exists() else None
    load_before = os.getloadavg()
    result = {"machine": machine_info(), "uptime_s": uptime, "load_avg_before": load_before,
              "note": "shared machine: other processes may run during the measurement (see load averages)",
              "args": {k: str(v) for k, v in vars(args).items()},
              **run(args.tasks, args.sizes, args.ppo_size or None, args.ppo_task, args.steps, args.warmup,
                    args.split_size or None)}
    result["load_avg_after"] = os.getloadavg()
    result["wall_s"] = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = args.out / "rl_env.json.tmp"
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(args.out / "rl_env.json")
    print()
    print(markdown(result))
    return result


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
