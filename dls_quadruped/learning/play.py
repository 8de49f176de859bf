"""Run a trained policy and write plots (and a video where offscreen rendering works).

    python -m dls_quadruped.learning.play --task base --checkpoint runs/base/<run>/model_100.pt --seconds 10

Writes to ``<out>`` (default: next to the checkpoint, ``play/``): ``tracking.png`` (commanded vs
measured v_x, v_y, omega_z of env 0), ``gait.png`` (Hildebrand-style gait diagram: one row per leg,
a bar while the foot is in contact) and ``play.npz`` (the raw traces). Video rendering is not
implemented yet (known gap, docs/train.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp.observations import base_lin_vel, foot_contact
from dls_quadruped.learning.runner import AtomicOnPolicyRunner, runner_config
from dls_quadruped.robots.aliengo import constants as C


def rollout(env: LocomotionEnv, policy, steps: int) -> dict[str, np.ndarray]:
    """Run ``policy`` (TensorDict -> (B, 28)) for ``steps`` policy steps; traces of env 0."""
    obs = env.get_observations()
    cmd, vel, contact = [], [], []
    with torch.no_grad():
        for _ in range(steps):
            obs, _, _, _ = env.step(policy(obs))
            v = base_lin_vel(env)
            cmd.append(env.command_manager.command[0].cpu().numpy().copy())
            vel.append(np.r_[v[0, :2].cpu().numpy(), env.state.base_ang_vel_b[0, 2].item()])
            contact.append(foot_contact(env)[0].cpu().numpy())
    return {"t": np.arange(1, steps + 1) * env.step_dt, "command": np.array(cmd), "velocity": np.array(vel),
            "contact": np.array(contact)}


def plot_tracking(trace: dict, path: Path) -> None:
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 6))
    for i, (ax, label) in enumerate(zip(axes, ("v_x [m/s]", "v_y [m/s]", "omega_z [rad/s]"))):
        ax.plot(trace["t"], trace["command"][:, i], "k--", label="command")
        ax.plot(trace["t"], trace["velocity"][:, i], label="measured (base frame)")
        ax.set_ylabel(label)
    axes[0].legend(loc="upper right")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_gait(trace: dict, path: Path, dt: float) -> None:
    """Hildebrand-style diagram: a bar per leg for each stance interval."""
    fig, ax = plt.subplots(figsize=(8, 2.5))
    for leg, name in enumerate(C.LEG_NAMES):
        c = trace["contact"][:, leg] > 0.5
        edges = np.flatnonzero(np.diff(np.r_[0, c.astype(int), 0]))
        spans = [(trace["t"][a] - dt, (b - a) * dt) for a, b in zip(edges[::2], edges[1::2])]
        ax.broken_barh(spans, (leg - 0.4, 0.8), color="k")
    ax.set_yticks(range(C.NUM_LEGS), C.LEG_NAMES)
    ax.invert_yaxis()
    ax.set_xlabel("time [s]")
    ax.set_title("gait diagram (black = stance)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="base")
    p.add_argument("--checkpoint", type=Path, default=None, help="model_<it>.pt; none = zero action (feed-forward)")
    p.add_argument("--num-envs", type=int, default=4)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--num-workers", type=int, default=0)
    args = p.parse_args(argv)
    task = load_task(args.task, overrides={"scene": {"num_workers": args.num_workers}})
    env = LocomotionEnv(task, num_envs=args.num_envs, verbose=False)
    out = args.out or (args.checkpoint.parent / "play" if args.checkpoint else Path("runs") / task.name / "play")
    out.mkdir(parents=True, exist_ok=True)
    try:
        if args.checkpoint is not None:
            runner = AtomicOnPolicyRunner(env, runner_config(task.data["agent"]), log_dir=None)
            runner.load(str(args.checkpoint))
            policy = runner.get_inference_policy()
        else:
            def policy(obs):
                return torch.zeros(env.num_envs, env.num_actions)
        trace = rollout(env, policy, round(args.seconds / env.step_dt))
    finally:
        env.close()
    np.savez(out / "play.npz", **trace)
    plot_tracking(trace, out / "tracking.png")
    plot_gait(trace, out / "gait.png", env.step_dt)
    print(f"[play] wrote {out}/tracking.png, gait.png, play.npz")
    return out


if __name__ == "__main__":
    main()
