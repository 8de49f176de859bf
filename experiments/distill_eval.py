"""Evaluation of the distillation experiments' students (thesis 7.2): SP and test MSE of every seed and snapshot.

Everything is evaluated in one batched env (:func:`evaluate`), each policy on its own slot of
``sp_episodes`` robots, every slot playing the *same* scheduled episodes (keys 0 .. E-1 of the SP
seed): the expert once, one untrained student per encoding (r_0 of eq. 7.2.2: seed 0's
initialisation of that encoding), every seed's trained student (and every epoch's, for Fig. 24);
one more slot is the expert on held-out keys, recorded whole, from which the MSE test set is cut
(``learning.distill_test_set``: windows spread over every phase of 15 s episodes, the same test
states for every run of every script: start steps drawn for the largest span of all, H = 15 at
dt = 0.04 s). SP and MSE are given per seed and over seeds with a two-level bootstrap interval
(seeds and episodes, ``distill_metrics.sp_over_seeds`` / ``mse_over_seeds``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from dls_quadruped.learning.distill import distill_task, load_expert
from dls_quadruped.learning.distill_metrics import (
    mse_over_seeds,
    slot_returns,
    sp_over_seeds,
    survival,
)
from dls_quadruped.learning.distill_test_set import cut_windows, window_starts
from dls_quadruped.learning.student import Student, encode_labels
from experiments.distill_common import ACTIVATION, HIDDEN, SCALES, TASK

SP_SEED = 2000
"""Schedule seed of the evaluation env: SP episodes are keys 0 .. E-1."""
TEST_KEY = 1_000_000
"""The MSE test set's episodes are keys TEST_KEY + 0 .. E_test-1 of the SP seed (never played by an SP slot)."""
TEST_SPAN = 29
"""Window starts of the test set leave room for the largest span of any run, (15 - 1) x 2 + 1 steps."""
STEP_DT = 0.02
"""[s] env step of the distillation task (checked against the env by ``EncodingSection.stride``)."""
MAX_ROBOTS = 2048
"""Robots per evaluation env; more slots than fit go to further envs (same keys: same episodes)."""


def trained_student(state: dict, cfg: dict) -> Student:
    """The student of a run's config with a trained state dict (its snapshot of one seed), in eval mode."""
    s = Student(259, net_encoding(cfg), HIDDEN, ACTIVATION)
    s.load_state_dict(state)
    return s.eval()


def _enc_key(cfg: dict) -> tuple:
    e = cfg["encoding"]
    return (e["p"], e["F"], e["horizon"], e["constrained_fit"])


def untrained_returns(ev: dict, cfg: dict) -> list[float]:
    """The (E,) returns of the untrained student (r_0) of ``cfg``'s encoding in an :func:`evaluate` result."""
    return ev["returns"]["untrained"][" ".join(map(str, _enc_key(cfg)))]


def _untrained(key: tuple) -> Student:
    """r_0 of an encoding: seed 0's initialisation (fresh normaliser)."""
    from dls_quadruped.mpc.config import EncodingConfig

    torch.manual_seed(0)
    return Student(259, EncodingConfig(*key), HIDDEN, ACTIVATION).eval()


def _first_action(net):
    return lambda obs: net.first_action(obs)


def _test_mse(trained: dict, record, args: argparse.Namespace) -> dict[str, list[dict]]:
    """{run: [mse_over_seeds per snapshot]} on windows cut from ``record`` at the same starts for all."""
    count = SCALES[args.scale]["evaluate"]["test_datapoints"]
    episode, start = window_starts(record.length, TEST_SPAN, count, seed=SP_SEED)
    n_ep = len(record.length)
    per_episode = torch.bincount(episode, minlength=n_ep).double()
    out: dict[str, list[dict]] = {}
    for name, res in trained.items():
        cfg = res["config"]
        stride = round(cfg["encoding"]["dt"] / STEP_DT)
        horizon = cfg["encoding"]["horizon"]
        if (horizon - 1) * stride + 1 > TEST_SPAN:
            raise ValueError(f"{name}: span {(horizon - 1) * stride + 1} > TEST_SPAN {TEST_SPAN}")
        obs, acts = cut_windows(record, episode, start, horizon, stride)
        rows = []
        for j in range(len(res["snapshot_epochs"])):
            sq = torch.zeros(len(res["seeds"]), n_ep, dtype=torch.float64)
            for k in range(len(res["seeds"])):
                net = trained_student(res["students"][k][j], cfg)
                labels = encode_labels(acts, net_encoding(cfg))
                with torch.no_grad():
                    err = (net.net(obs) - labels).square().mean(-1).double()  # (N,) per window, over outputs
                sq[k].index_add_(0, episode, err)
            m = mse_over_seeds(sq.numpy(), per_episode.numpy(), seed=j)
            m["epoch"] = res["snapshot_epochs"][j]
            rows.append(m)
        out[name] = rows
    return out


def net_encoding(cfg: dict):
    from dls_quadruped.mpc.config import EncodingConfig

    e = cfg["encoding"]
    return EncodingConfig(e["p"], e["F"], e["horizon"], e["constrained_fit"])


def evaluate(trained: dict[str, dict], args: argparse.Namespace, overrides: dict | None = None) -> dict:
    """SP and test MSE of every seed and snapshot of every run, all in batched envs on the same episodes;
    ``overrides``: task sections changed in the evaluation env (Table 11's noise and pushes), the test set too.

    Returns:
        {"sp": {run: [sp_over_seeds + survival per snapshot]}, "mse": {run: [mse_over_seeds per
        snapshot]}, "returns": {"expert": (E,), "untrained": {encoding: (E,)}, run: [(K, E) per snapshot]},
        "seconds"}.
    """
    from dls_quadruped.envs.env import LocomotionEnv

    t0 = time.monotonic()
    per = SCALES[args.scale]["evaluate"]["sp_episodes"]
    n_test = SCALES[args.scale]["evaluate"]["test_episodes"]
    if n_test > per:
        raise ValueError(f"test_episodes {n_test} > sp_episodes {per}: the test slot has sp_episodes robots")
    expert = load_expert(args.expert)
    encodings = sorted({_enc_key(res["config"]) for res in trained.values()})
    students = [(name, k, j) for name, res in trained.items() for k in range(len(res["seeds"]))
                for j in range(len(res["snapshot_epochs"]))]
    # slot 0: expert on the SP episodes, 1: expert on the test episodes, then r_0 per encoding
    refs: list[tuple[str, object]] = [("expert", expert), ("test", expert)]
    refs += [(f"untrained {e}", _untrained(e)) for e in encodings]
    cap = MAX_ROBOTS // per
    batches = [students[:max(1, cap - len(refs))]]
    rest = students[len(batches[0]):]
    batches += [rest[i:i + cap] for i in range(0, len(rest), cap)]
    ret: dict[tuple, np.ndarray] = {}
    surv: dict[tuple, np.ndarray] = {}
    record = None
    for b, group in enumerate(batches):
        slots = (refs if b == 0 else []) + [((name, k, j), trained_student(trained[name]["students"][k][j],
                                                                    trained[name]["config"])) for name, k, j in group]
        keys = torch.arange(per).repeat(len(slots))
        if b == 0:
            keys[per:2 * per] += TEST_KEY
        env = LocomotionEnv(distill_task(TASK, None, overrides), num_envs=len(slots) * per, verbose=False)
        try:
            t1 = time.monotonic()
            print(f"[{args.out.name}] evaluation {b + 1}/{len(batches)}: {len(slots)} policies x {per} episodes of "
                  f"{env.max_episode_length_s:g} s ({env.num_envs} robots)", flush=True)
            res = slot_returns(env, [_first_action(p) if isinstance(p, Student) else p for _, p in slots], SP_SEED,
                               keys, record=1 if b == 0 else None)
            print(f"[{args.out.name}] evaluation {b + 1} done in {time.monotonic() - t1:.0f} s", flush=True)
        finally:
            env.close()
        if b == 0:
            record = res["record"]
        for i, (key, _) in enumerate(slots):
            ret[key], surv[key] = res["return"][i], res["survived"][i]
    record.obs, record.actions, record.length = (x[:n_test] for x in (record.obs, record.actions, record.length))
    r_exp = ret["expert"]
    sp_out: dict[str, list[dict]] = {}
    returns: dict = {"expert": r_exp.tolist(), "untrained": {}}
    for e in encodings:
        returns["untrained"][" ".join(map(str, e))] = ret[f"untrained {e}"].tolist()
    for name, res in trained.items():
        r_0 = ret[f"untrained {_enc_key(res['config'])}"]
        rows, raw = [], []
        for j, epoch in enumerate(res["snapshot_epochs"]):
            r = np.stack([ret[(name, k, j)] for k in range(len(res["seeds"]))])
            s_all = np.stack([surv[(name, k, j)] for k in range(len(res["seeds"]))])
            sp = sp_over_seeds(r, r_exp, r_0, seed=j)
            sp["survival"] = survival(s_all.flatten())  # K x E episodes (the E are shared by the seeds)
            sp["survival_per_seed"] = [float(x) for x in s_all.mean(1)]
            sp["survival_expert"] = survival(surv["expert"])
            sp["survival_untrained"] = survival(surv[f"untrained {_enc_key(res['config'])}"])
            sp["epoch"] = epoch
            rows.append(sp)
            raw.append(r.tolist())
        sp_out[name] = rows
        returns[name] = raw
    mse = _test_mse(trained, record, args)
    return {"sp": sp_out, "mse": mse, "returns": returns, "seconds": time.monotonic() - t0,
            "test_set": {"episodes": n_test, "steps": int(record.length.sum()), "windows":
                         SCALES[args.scale]["evaluate"]["test_datapoints"], "span": TEST_SPAN,
                         "schedule_seed": SP_SEED, "keys": f"{TEST_KEY} + 0..{n_test - 1}"}}

