"""Export a horizon-space PPO actor (``base_mpc_cost``) as a student program, for the closed loop's ``--student``.

The inverse of ``experiments/mpc_cost_init.py``: the checkpoint's actor (an MLP from the 259 observations to the
encoded horizon in raw units) becomes a ``learning.student.Student`` whose normaliser is the actor's own (a run from
scratch keeps rsl-rl's running normaliser, the same ``EmpiricalNormalization``) or, without one (the runs started
from the student, whose normaliser was folded into the first layer), the identity (mean 0, sigma + eps = 1), and
whose last layer's rows are divided by the output scale (the student multiplies them back), so the program's
output is the actor's mean exactly; the encoding metadata (p, F, H, dt, from
the task's ``actions.horizon``) goes with it, so ``rl_warm_start`` checks it against the MPC like any student.

    python -m experiments.mpc_cost_export runs/base_mpc_cost/w0.1_s0/model_499.pt --out runs/mpc_cost/w0.1_s0.pt2
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.managers.action import resolve_horizon_config
from dls_quadruped.learning.runner import read_checkpoint
from dls_quadruped.learning.student import Student, export_student, metadata
from dls_quadruped.mpc.config import EncodingConfig


def student_from_actor(actor: dict, enc: EncodingConfig, obs_dim: int, activation: str = "elu") -> Student:
    """A :class:`Student` computing ``actor``'s mean (an rsl-rl ``MLPModel`` state dict, with or without its
    observation normaliser)."""
    layers = sorted(int(k.split(".")[1]) for k in actor if k.startswith("mlp.") and k.endswith(".weight"))
    hidden = [int(actor[f"mlp.{i}.weight"].shape[0]) for i in layers[:-1]]
    student = Student(obs_dim, enc, hidden, activation)
    state = {k.removeprefix("mlp."): v.clone() for k, v in actor.items() if k.startswith("mlp.")}
    last = layers[-1]
    state[f"{last}.weight"] = state[f"{last}.weight"] / student.output_scale[:, None]
    state[f"{last}.bias"] = state[f"{last}.bias"] / student.output_scale
    student.mlp.load_state_dict(state)
    norm = student.obs_normalizer
    own = {k.removeprefix("obs_normalizer."): v for k, v in actor.items() if k.startswith("obs_normalizer.")}
    if own:
        norm.load_state_dict(own)  # the actor's running normaliser, frozen (eval mode)
        return student.eval()
    with torch.no_grad():  # identity: (x - 0) / (sigma + eps) with sigma + eps = 1
        norm._mean.zero_()
        norm._std.fill_(1.0 - norm.eps)
        norm._var.copy_(norm._std**2)
    return student.eval()


def main(argv: list[str] | None = None) -> Path:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path, help="a base_mpc_cost training checkpoint (model_<it>.pt or a resume copy)")
    p.add_argument("--task", default="base_mpc_cost", help="the task whose actions.horizon the actor acts in")
    p.add_argument("--out", type=Path, required=True, help="the student program to write (.pt2)")
    args = p.parse_args(argv)
    horizon = resolve_horizon_config(load_task(args.task))
    if horizon is None:
        raise UserError(f"task {args.task} has no actions.horizon")
    enc, dt = horizon
    try:
        ckpt = read_checkpoint(args.checkpoint)
    except (ValueError, FileNotFoundError) as err:
        raise UserError(f"cannot read {args.checkpoint}: {err}") from None
    obs_dim = int(ckpt["obs_dims"]["policy"])
    student = student_from_actor(ckpt["actor_state_dict"], enc, obs_dim)
    extra = {"source": str(args.checkpoint), "iteration": int(ckpt["iter"]), "algorithm": "ppo_mpc_cost"}
    export_student(student, metadata(enc, dt, obs_dim, extra), args.out)
    print(f"wrote {args.out} (and {args.out.with_suffix('.json')}): the actor of {args.checkpoint}, "
          f"iteration {ckpt['iter']}")
    return args.out


if __name__ == "__main__":
    run_cli(main)
