"""Throughput of distillation at the Table-7 defaults: collection datapoints/s and gradient steps/s.

    OMP_NUM_THREADS=1 python -m dls_quadruped.learning.distill_bench --num-envs 128 --datapoints 4000

Collection is timed with the expert driving (beta = 1) and with DAgger's mixture (beta = 0.6, one
student forward more per env step); training with mini-batches of 64 read from the disk dataset.
The projection of a full Table-7 run (30 epochs x 80 000 datapoints, cap 800 000, one pass per
epoch) uses these rates; SP evaluations come on top (reported separately, env-bound like collection).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, positive_int, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.learning.collect import collect
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill import distill_task, load_expert
from dls_quadruped.learning.student import Student, encode_labels
from dls_quadruped.mpc.config import EncodingConfig


def table7_steps(epochs: int = 30, per_epoch: int = 80_000, cap: int = 800_000, batch: int = 64) -> int:
    """Gradient steps of one pass per epoch over a dataset that grows by ``per_epoch`` up to ``cap``."""
    return sum(-(-min(cap, per_epoch * (i + 1)) // batch) for i in range(epochs))


def main(argv: list[str] | None = None) -> dict:
    from dls_quadruped.envs.env import LocomotionEnv

    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--num-envs", type=positive_int, default=128)
    p.add_argument("--datapoints", type=positive_int, default=4000)
    p.add_argument("--train-steps", type=positive_int, default=1500)
    p.add_argument("--expert", default="docs/policies/base_actor.pt")
    p.add_argument("--out", type=Path, default=Path("results") / "bench" / "distill.json")
    args = p.parse_args(argv)
    enc = EncodingConfig("first", "spline", 10)
    expert = load_expert(args.expert)
    env = LocomotionEnv(distill_task("base", None), num_envs=args.num_envs, verbose=False)
    load_before = os.getloadavg()
    out: dict = {"cpu": cpu_model(), "cores": os.cpu_count(), "torch_threads": torch.get_num_threads(),
                 "num_envs": args.num_envs, "encoding": "first-spline H=10 dt=0.02"}
    try:
        torch.manual_seed(0)
        student = Student(259, enc, [512, 256, 128], "elu")
        with tempfile.TemporaryDirectory() as tmp:
            ds = DiskDataset.create(Path(tmp) / "d", 259, 64, 800_000)
            for b in (1.0, 0.6):
                info = collect(env, expert, lambda a: encode_labels(a, enc), args.datapoints, enc, 1, ds.append,
                               beta_value=b, student=student.first_action)
                out[f"collect_beta_{b:g}"] = {**info, "datapoints_per_s": info["datapoints"] / info["seconds"],
                                              "env_steps_per_s": info["env_steps"] * args.num_envs / info["seconds"]}
            opt = torch.optim.Adadelta(student.parameters(), lr=1.0)
            gen = torch.Generator().manual_seed(0)
            steps, t0 = 0, time.monotonic()
            while steps < args.train_steps:
                for obs, labels in ds.minibatches(64, gen):
                    loss = torch.nn.functional.mse_loss(student.net(obs), labels)
                    opt.zero_grad(set_to_none=True)
                    loss.backward()
                    opt.step()
                    steps += 1
                    if steps >= args.train_steps:
                        break
            seconds = time.monotonic() - t0
            out["train"] = {"steps": steps, "seconds": seconds, "steps_per_s": steps / seconds, "batch": 64}
    finally:
        env.close()
    rate_c = out["collect_beta_0.6"]["datapoints_per_s"]
    n_steps = table7_steps()
    out["table7_projection"] = {
        "datapoints": 30 * 80_000, "gradient_steps": n_steps,
        "collect_s": 30 * 80_000 / rate_c, "train_s": n_steps / out["train"]["steps_per_s"],
    }
    out["table7_projection"]["total_min_without_sp"] = (out["table7_projection"]["collect_s"]
                                                         + out["table7_projection"]["train_s"]) / 60
    out["load_average"] = {"before": load_before, "after": os.getloadavg()}
    write_json(out, args.out)
    print(f"[distill_bench] {out['cpu']} ({out['cores']} cores), load {load_before[0]:.1f} -> "
          f"{os.getloadavg()[0]:.1f}: "
          f"collection {out['collect_beta_1']['datapoints_per_s']:.0f} datapoints/s (expert drives), "
          f"{rate_c:.0f}/s (DAgger beta 0.6); training {out['train']['steps_per_s']:.0f} steps/s (batch 64); "
          f"Table-7 run ~{out['table7_projection']['total_min_without_sp']:.0f} min + SP; wrote {args.out}", flush=True)
    return out


if __name__ == "__main__":
    run_cli(main)
