"""Networks for ``train --init-from`` from a distilled student: PPO in the MPC's horizon space starts where DAgger
ended.

A student (``learning.student``) is an observation normaliser and an MLP whose output, times ``output_scale`` (x10
on the spline curvature parameters), is the encoded horizon in raw action units; rsl-rl's actor (``MLPModel``) is
an MLP of the same sizes and a Gaussian std, here without an observation normaliser (``base_mpc_cost`` sets
``agent.actor.obs_normalization: false``): the student's normaliser, fit on its distillation data, is folded into
the first layer, W' = W / (sigma + eps), b' = b - W' mu (rsl-rl's ``EmpiricalNormalization``: (x - mu) /
(sigma + eps)). Left as a running normaliser it moves with the first PPO rollouts (the projected gravity's z has
sigma = 0.003 there) and shifts the policy by a KL of ~12 per rollout before any gradient step. The last layer's rows
are multiplied by ``output_scale``, so the actor's mean is the student's output exactly, and each output gets
``--std-scale`` (0.3) times the expert's final std of the scalar it encodes (``--std`` sets one value instead): with
the expert's full std the noise itself dominates the trajectory cost (median c 23 against 8 without noise, 18 % of
the plans past a clip of 50), at 0.3 of it the median is 10. The student has no critic:
the expert's critic (``--critic-from``, the same 259 observations) is the closest value function of the base
reward, which the task keeps. The file has the layout of ``docs/policies/*_networks.pt``.

    python -m experiments.mpc_cost_init                                  # -> runs/mpc_cost/student_networks.pt
    python -m dls_quadruped.learning.train --task base_mpc_cost --init-from runs/mpc_cost/student_networks.pt

Raises a named error when the student's encoding or observation size is not the task's ``actions.horizon``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.managers.action import resolve_horizon_config
from dls_quadruped.learning.runner import read_checkpoint
from dls_quadruped.learning.student import load_student
from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.encodings import SPLINE_PARAMS, block_slices, encoded_dim

STUDENT = Path("docs/policies/base_recipe_student_first_spline_h10.pt2")
CRITIC = Path("docs/policies/base_recipe_networks.pt")
OUT = Path("runs/mpc_cost/student_networks.pt")


def expert_std_per_entry(std28: torch.Tensor, enc: EncodingConfig) -> torch.Tensor:
    """(D,) the std of the 28-vector's scalar that each encoded entry encodes (f, d, each p and F scalar)."""
    sl = block_slices(enc)
    out = torch.empty(encoded_dim(enc))
    out[sl["f"]], out[sl["d"]] = std28[0:4], std28[4:8]
    for name, kind, part in (("p", enc.p, std28[8:16]), ("F", enc.F, std28[16:28])):
        if kind == "discrete":
            out[sl[name]] = part.repeat(enc.horizon)
        elif kind == "spline":
            out[sl[name]] = part.repeat_interleave(SPLINE_PARAMS)
        else:
            out[sl[name]] = part
    return out


def student_networks(student_path: Path, critic_path: Path, enc: EncodingConfig, dt: float,
                     std: float | None = None, std_scale: float = 0.3) -> dict:
    """The ``--init-from`` checkpoint dict: the student as the actor, ``critic_path``'s critic (see module doc)."""
    module, meta = load_student(student_path)
    want = {"p": enc.p, "F": enc.F, "horizon": enc.horizon, "constrained_fit": enc.constrained_fit}
    got = meta.get("encoding", {})
    wrong = [f"{k} {got.get(k)!r} (task: {v!r})" for k, v in want.items() if got.get(k) != v]
    if abs(float(got.get("dt", float("nan"))) - dt) > 1e-9:
        wrong.append(f"dt {got.get('dt')!r} (task: {dt!r})")
    if wrong:
        raise UserError(f"student {student_path} does not encode the task's actions.horizon: {', '.join(wrong)}")
    source = read_checkpoint(critic_path)
    if int(meta["obs_dim"]) != source["obs_dims"]["policy"]:
        raise UserError(f"student {student_path} reads {meta['obs_dim']} observations, the critic of {critic_path} "
                        f"{source['obs_dims']['policy']}")
    state = (module.program if hasattr(module, "program") else module).state_dict()  # a program, or TorchScript
    params = {k.split("student.", 1)[-1]: v.detach().clone() for k, v in state.items()}
    actor = {k: v for k, v in params.items() if k.startswith("mlp.")}
    eps = 1e-2  # rsl_rl.modules.EmpiricalNormalization's default, the student's normaliser
    w0 = actor["mlp.0.weight"] / (params["obs_normalizer._std"] + eps)  # (hidden, obs) / (1, obs)
    actor["mlp.0.bias"] = actor["mlp.0.bias"] - w0 @ params["obs_normalizer._mean"][0]
    actor["mlp.0.weight"] = w0
    last = max(int(k.split(".")[1]) for k in actor)
    scale = params["output_scale"]
    actor[f"mlp.{last}.weight"] = actor[f"mlp.{last}.weight"] * scale[:, None]
    actor[f"mlp.{last}.bias"] = actor[f"mlp.{last}.bias"] * scale
    std28 = source["actor_state_dict"]["distribution.std_param"]
    actor["distribution.std_param"] = (torch.full((encoded_dim(enc),), float(std)) if std is not None
                                       else std_scale * expert_std_per_entry(std28, enc))
    return {"actor_state_dict": actor, "critic_state_dict": source["critic_state_dict"], "iter": 0,
            "obs_dims": dict(source["obs_dims"]), "num_actions": encoded_dim(enc),
            "infos": {"source": f"actor: student {student_path}; critic: {critic_path}",
                      "contents": "actor and critic only (no optimiser, no env state): for train --init-from"}}


def main(argv: list[str] | None = None) -> Path:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--student", type=Path, default=STUDENT)
    p.add_argument("--critic-from", type=Path, default=CRITIC)
    p.add_argument("--task", default="base_mpc_cost", help="the task whose actions.horizon the student must encode")
    p.add_argument("--std", type=float, default=None, help="one exploration std for every output (default: "
                                                           "--std-scale x the expert's, per encoded scalar)")
    p.add_argument("--std-scale", type=float, default=0.3, help="factor on the expert's std (default 0.3)")
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args(argv)
    horizon = resolve_horizon_config(load_task(args.task))
    if horizon is None:
        raise UserError(f"task {args.task} has no actions.horizon: its policy does not act in a horizon space")
    ckpt = student_networks(args.student, args.critic_from, *horizon, std=args.std, std_scale=args.std_scale)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + ".tmp")
    torch.save(ckpt, tmp)
    os.replace(tmp, args.out)
    print(f"wrote {args.out}: actor from {args.student} ({ckpt['num_actions']} outputs), "
          f"critic from {args.critic_from}")
    return args.out


if __name__ == "__main__":
    run_cli(main)
