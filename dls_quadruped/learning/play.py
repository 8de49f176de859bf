"""Play a policy on a task and write plots (and a video where offscreen rendering works).

    python -m dls_quadruped.learning.play --task rough                      # the newest checkpoint of the latest run
    python -m dls_quadruped.learning.play --task base --checkpoint runs/base/<run>/model_100.pt --seconds 10
    python -m dls_quadruped.learning.play --task base --checkpoint docs/policies/base_actor.pt
    python -m dls_quadruped.learning.play --task base --set commands.base_velocity.params.max_speed=0.5 --seconds 20

``--checkpoint`` takes an rsl-rl checkpoint (``model_<it>.pt``), an exported actor
(``runs/<task>/<run>/exported/policy.pt2``) or a committed one (``docs/policies/<name>_actor.pt``); without
it, play takes the newest readable ``model_<it>.pt`` of the task's latest run under ``--log-root``
(``runs/<task>/``) and stops with one line when there is none. ``--zero-action`` plays the zero latent
action instead (the feed-forward trot of the low-level controller). ``--set KEY=VALUE`` overrides the
task file (``cli.add_set_argument``).

Writes to ``<out>`` (default: ``play/`` next to a checkpoint under ``--log-root``, else
``<log-root>/<task>/play/<file stem>``): ``tracking.png`` (commanded vs measured v_x, v_y, omega_z of
env 0), ``gait.png`` (Hildebrand-style gait diagram: one row per leg, a bar while the foot is in
contact), ``play.npz`` (the raw traces of env 0, its raw latent action included) and ``video.gif`` of
env 0 (MuJoCo offscreen rendering, EGL by default; 25 frames/s; if rendering is unavailable the reason
is printed and the plots are still written). GIF because Pillow comes with matplotlib; no video codec
dependency is needed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must be set before mujoco is imported

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import mujoco
import numpy as np
import torch

from dls_quadruped.cli import (
    ArgumentParser,
    UserError,
    add_set_argument,
    non_negative_int,
    positive_float,
    positive_int,
    run_cli,
    set_overrides,
)
from dls_quadruped.envs.config import load_task, merge_overrides
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp.observations import base_lin_vel, foot_contact
from dls_quadruped.eval.policy import load_policy
from dls_quadruped.learning.runner import latest_run, newest_readable_checkpoint
from dls_quadruped.robots.aliengo import constants as C

CHECKPOINT_KINDS = "a model_<it>.pt, an exported policy.pt2 or a committed docs/policies/<name>_actor.pt"


class Recorder:
    """Renders env 0 from its state with a tracking camera (a local MjData of the env's model)."""

    def __init__(self, model: mujoco.MjModel, width: int = 480, height: int = 360):
        self.model = model
        self.data = mujoco.MjData(model)
        self.renderer = mujoco.Renderer(model, height, width)
        self.camera = mujoco.MjvCamera()
        self.camera.distance, self.camera.azimuth, self.camera.elevation = 2.0, 135.0, -20.0
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:4] = 1  # the robot's collision primitives (group 3) are its only body shapes
        self.frames: list[np.ndarray] = []

    def capture(self, env: LocomotionEnv) -> None:
        s = env.state
        self.data.qpos[:3] = s.base_pos_w[0].cpu().numpy()
        self.data.qpos[3:7] = s.base_quat_w[0].cpu().numpy()
        self.data.qpos[7:19] = s.joint_pos[0].cpu().numpy()
        mujoco.mj_forward(self.model, self.data)
        self.camera.lookat[:] = self.data.qpos[:3]
        self.renderer.update_scene(self.data, camera=self.camera, scene_option=self.option)
        self.frames.append(self.renderer.render().copy())

    def save(self, path: Path, fps: float) -> None:
        from PIL import Image

        images = [Image.fromarray(f) for f in self.frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)


def rollout(env: LocomotionEnv, policy, steps: int, recorder: Recorder | None = None,
            frame_every: int = 2) -> dict[str, np.ndarray]:
    """Run ``policy`` (TensorDict -> (B, 28)) for ``steps`` policy steps; traces of env 0: time [s], command
    (steps, 3), measured velocity (steps, 3), foot contact (steps, 4), raw latent action (steps, 28)."""
    obs = env.get_observations()
    cmd, vel, contact, act = [], [], [], []
    with torch.no_grad():
        for k in range(steps):
            action = policy(obs)
            act.append(action[0].cpu().numpy().copy())
            obs, _, _, _ = env.step(action)
            if recorder is not None and k % frame_every == 0:
                recorder.capture(env)
            v = base_lin_vel(env)
            cmd.append(env.command_manager.command[0].cpu().numpy().copy())
            vel.append(np.r_[v[0, :2].cpu().numpy(), env.state.base_ang_vel_b[0, 2].item()])
            contact.append(foot_contact(env)[0].cpu().numpy())
    return {"t": np.arange(1, steps + 1) * env.step_dt, "command": np.array(cmd), "velocity": np.array(vel),
            "contact": np.array(contact), "action": np.array(act)}


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


def run_checkpoint(task_dir: Path, task: str) -> Path:
    """The newest readable ``model_<it>.pt`` of the latest run in ``task_dir`` (``runs/<task>``).

    Raises:
        UserError: no run holds a checkpoint, or the latest run's are all unreadable.
    """
    run = latest_run(task_dir)
    if run is None:
        raise UserError(f"no checkpoint under {task_dir}/; train one with make train TASK={task}, "
                        f"or pass --checkpoint ({CHECKPOINT_KINDS})")
    found = newest_readable_checkpoint(run, prog="play")
    if found is None:
        raise UserError(f"no readable checkpoint in {run}, the latest run under {task_dir}/; "
                        f"pass --checkpoint ({CHECKPOINT_KINDS})")
    return found[0]


def default_out(source: Path | None, task: str, log_root: Path) -> Path:
    """``play/`` next to a checkpoint under ``log_root``; else ``<log_root>/<task>/play/<file stem>``
    (``zero_action`` for no policy), so a committed policy's folder gets nothing written into it."""
    if source is not None and source.resolve().is_relative_to(log_root.resolve()):
        return source.parent / "play"
    return log_root / task / "play" / (source.stem if source is not None else "zero_action")


def main(argv: list[str] | None = None) -> Path:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="base",
                   help="task name in tasks/ (python -m dls_quadruped.list_tasks) or a YAML path")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help=f"what to play: {CHECKPOINT_KINDS}; default: the newest readable model_<it>.pt of the "
                        "task's latest run under --log-root")
    p.add_argument("--zero-action", action="store_true",
                   help="play the zero latent action (the low-level controller's feed-forward trot), no policy")
    p.add_argument("--log-root", type=Path, default=Path("runs"), help="train's runs: <log-root>/<task>/<run>/")
    p.add_argument("--num-envs", type=positive_int, default=4)
    p.add_argument("--seconds", type=positive_float, default=10.0)
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: play/ beside a checkpoint of a run under --log-root, else "
                        "<log-root>/<task>/play/<checkpoint stem>)")
    p.add_argument("--num-workers", type=non_negative_int, default=0)
    p.add_argument("--no-video", action="store_true", help="skip the GIF (the plots and play.npz are still written)")
    add_set_argument(p)
    args = p.parse_args(argv)
    if args.zero_action and args.checkpoint is not None:
        p.error("argument --zero-action: not with --checkpoint (play one or the other)")
    if args.checkpoint is not None and not args.checkpoint.is_file():
        p.error(f"--checkpoint {args.checkpoint}: no such file (expected {CHECKPOINT_KINDS})")
    task = load_task(args.task, overrides=merge_overrides({"scene": {"num_workers": args.num_workers}},
                                                          set_overrides(args.set)))
    source = None if args.zero_action else args.checkpoint or run_checkpoint(args.log_root / task.name, task.name)
    print(f"[play] task {task.name}: " + (f"playing {source}" if source is not None else "zero action"))
    out = args.out or default_out(source, task.name, args.log_root)
    env = LocomotionEnv(task, num_envs=args.num_envs, verbose=False)
    try:
        if source is not None:  # the networks only: play shows the task's own command ranges and terrain
            policy = load_policy(source, env, flag="--checkpoint", same_task=True)
        else:
            def policy(obs):
                return torch.zeros(env.num_envs, env.num_actions)
        out.mkdir(parents=True, exist_ok=True)
        recorder = None
        if not args.no_video:
            try:
                recorder = Recorder(env.scene.model)
            except Exception as err:  # noqa: BLE001 - any GL failure only disables the video
                print(f"[play] no video: offscreen rendering unavailable ({type(err).__name__}: {err})")
        trace = rollout(env, policy, round(args.seconds / env.step_dt), recorder)
        if recorder is not None and recorder.frames:
            recorder.save(out / "video.gif", fps=1.0 / (2 * env.step_dt))
    finally:
        env.close()
    np.savez(out / "play.npz", **trace)
    plot_tracking(trace, out / "tracking.png")
    plot_gait(trace, out / "gait.png", env.step_dt)
    video = ", video.gif" if (out / "video.gif").is_file() else ""
    print(f"[play] wrote {out}: tracking.png, gait.png, play.npz{video}")
    return out


if __name__ == "__main__":
    run_cli(main)
