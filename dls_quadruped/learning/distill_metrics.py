"""Distillation metrics (thesis 7.2.1): test-set MSE (eq. 7.2.1) and simulation performance SP (eq. 7.2.2).

MSE: mean over the held-out datapoints and over the D outputs of (label - student)^2 in the label
space (spline curvature / 10, what the student is trained on), i.e. ``torch.nn.MSELoss``.

SP: the env is stepped with the decoded *first* action of the student for 15 s episodes (every
env one episode, started together from the same seeded resets for every policy), the base-task
reward is summed until the episode ends (a fall ends it early), and

    SP = (sum_i R_stud,i - sum_i R_0,i) / (sum_i R_exp,i - sum_i R_0,i)            (7.2.2)

with R_0 an untrained student and R_exp the expert on the same episodes. The 95 % interval is a
paired bootstrap over episodes (the same episode index is the same start and command for all
three policies). Survival (no termination but the time-out within the episode) has a Wilson interval.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from dls_quadruped.core.stats import wilson_interval
from dls_quadruped.envs import recorder
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill_test_set import ExpertEpisodes


@torch.no_grad()
def held_out_mse(net: Callable[[torch.Tensor], torch.Tensor], data: DiskDataset, batch: int = 8192) -> float:
    """Mean squared error (all rows, all outputs) of ``net`` (label-space outputs) on ``data``."""
    positions = data.positions()
    total, n = 0.0, 0
    for c in range(0, len(positions), batch):
        obs, labels = data.rows(positions[c:c + batch])
        total += float((net(obs) - labels).square().sum())
        n += labels.numel()
    return total / max(n, 1)


@torch.no_grad()
def episode_returns(env, policy: Callable[[torch.Tensor], torch.Tensor], seeds: list[int],
                    obs_group: str = "policy") -> dict[str, np.ndarray]:
    """One batch of episodes per seed (the env's schedule restarted with it: robot i plays episode 0
    of key i, the same for every policy), first episode only (``envs.recorder.record``).

    Under ``no_grad`` (the reset too) instead of ``inference_mode``: the env goes on collecting
    afterwards, and an in-process simulator would keep inference tensors created at a reset, which
    later in-place updates refuse.

    Returns:
        {"return": (E,) summed reward of the env (Σ_t Σ_k w_k r_k dt) until the first termination
        or the time-out, "survived": (E,) bool, not terminated before the time-out}.
    """
    returns, survived = [], []
    for seed in seeds:
        env.reset(seed=seed)
        rec = recorder.record(env, policy=policy, obs_group=obs_group, stop_when_all_ended=True, no_grad=True,
                              desc=f"SP episodes, seed {seed}")
        returns.append(rec.episode_return)
        survived.append(~rec.fell)
    return {"return": np.concatenate(returns), "survived": np.concatenate(survived)}


def simulation_performance(r_stud: np.ndarray, r_exp: np.ndarray, r_0: np.ndarray, n_boot: int = 2000,
                           seed: int = 0) -> dict:
    """SP (eq. 7.2.2) with a 95 % paired-bootstrap interval.

    Args:
        r_stud, r_exp, r_0: (E,) episode returns of the student, the expert and the untrained
            student on the same E episodes.
    """
    r_stud, r_exp, r_0 = (np.asarray(r, dtype=np.float64) for r in (r_stud, r_exp, r_0))
    if not r_stud.shape == r_exp.shape == r_0.shape or r_stud.ndim != 1:
        raise ValueError(f"returns must be three (E,) arrays, got {r_stud.shape}, {r_exp.shape}, {r_0.shape}")
    denom = r_exp.sum() - r_0.sum()
    sp = float((r_stud.sum() - r_0.sum()) / denom) if denom != 0 else float("nan")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(r_stud), size=(n_boot, len(r_stud)))
    d = r_exp[idx].sum(1) - r_0[idx].sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = (r_stud[idx].sum(1) - r_0[idx].sum(1)) / d
    boot = boot[np.isfinite(boot)]
    lo, hi = (np.percentile(boot, [2.5, 97.5]) if len(boot) else (float("nan"), float("nan")))
    return {"sp": sp, "ci95": [float(lo), float(hi)], "episodes": len(r_stud),
            "mean_return": {"student": float(r_stud.mean()), "expert": float(r_exp.mean()),
                            "untrained": float(r_0.mean())}}


def survival(survived: np.ndarray) -> dict:
    """Share of episodes that lasted the full 15 s, with its 95 % Wilson interval."""
    k, n = int(np.sum(survived)), len(survived)
    lo, hi = wilson_interval(k, n)
    return {"rate": k / max(n, 1), "ci95": [float(lo), float(hi)], "episodes": n}


@torch.no_grad()
def slot_returns(env, policies: list[Callable[[torch.Tensor], torch.Tensor]], seed: int, keys: torch.Tensor,
                 record: int | None = None, obs_group: str = "policy") -> dict:
    """Every policy on its own slot of robots in one env, one scheduled episode per robot
    (``envs.recorder.record``, under ``no_grad`` like :func:`episode_returns`).

    Args:
        env: ``LocomotionEnv`` with S x E robots; slot s (robots ``[s E, (s+1) E)``) is driven by
            ``policies[s]``.
        seed, keys: ``env.reset(seed=seed, episode_keys=keys)``; slots with the same keys play the
            same episodes (paired).
        record: a slot whose observations and actions are recorded (e.g. the expert on held-out
            keys, for the MSE test set, ``distill_test_set.ExpertEpisodes``).

    Returns:
        {"return": (S, E) float64 summed reward until the first end, "survived": (S, E) bool,
        "record": ExpertEpisodes of slot ``record`` (obs, actions, length) or None}.
    """
    slots = len(policies)
    per = env.num_envs // slots
    if per * slots != env.num_envs:
        raise ValueError(f"{env.num_envs} robots do not split into {slots} slots")

    def act(obs: torch.Tensor) -> torch.Tensor:
        return torch.cat([p(obs[s * per:(s + 1) * per]) for s, p in enumerate(policies)])

    env.reset(seed=seed, episode_keys=keys)
    kept = False if record is None else slice(record * per, (record + 1) * per)
    rec = recorder.record(env, policy=act, obs_group=obs_group, capture=kept, stop_when_all_ended=True, no_grad=True,
                          desc=f"{slots} policies x {per} episodes")
    return {"return": rec.episode_return.reshape(slots, per), "survived": (~rec.fell).reshape(slots, per),
            "record": None if record is None else ExpertEpisodes.from_record(rec, kept, seed)}


def _resample(k: int, e: int, n_boot: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n_boot, K) seed indices and (n_boot, E) episode indices, each drawn with replacement."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, k, size=(n_boot, k)), rng.integers(0, e, size=(n_boot, e))


def _interval(boot: np.ndarray) -> list[float]:
    boot = boot[np.isfinite(boot)]
    return [float(v) for v in np.percentile(boot, [2.5, 97.5])] if len(boot) else [float("nan")] * 2


def _sp_boot(r: np.ndarray, r_exp: np.ndarray, r_0: np.ndarray, ks: np.ndarray, es: np.ndarray) -> np.ndarray:
    """(n_boot,) SP of the seed-averaged return on resampled seeds ks and episodes es."""
    r_sum = r[:, es].sum(-1)  # (K, n_boot): each seed's return over resample b's episodes
    mean_sum = r_sum[ks, np.arange(len(es))[:, None]].mean(1)  # (n_boot,) mean over the resampled seeds
    with np.errstate(divide="ignore", invalid="ignore"):
        return (mean_sum - r_0[es].sum(-1)) / (r_exp[es].sum(-1) - r_0[es].sum(-1))


def sp_over_seeds(r_stud: np.ndarray, r_exp: np.ndarray, r_0: np.ndarray, n_boot: int = 2000, seed: int = 0) -> dict:
    """SP of K students (one per training seed) on the same E episodes, with two intervals.

    SP = (mean_k sum_e R_k,e - sum_e R_0,e) / (sum_e R_exp,e - sum_e R_0,e), the mean of the
    per-seed SPs (one denominator). ``ci95``: the combined interval, a two-level bootstrap that
    resamples the K seeds and, independently, the E episodes (the same episode indices for
    student, expert and r_0: paired); it holds both the seed-to-seed spread of training and the
    episode sampling. ``per_seed``: each seed's SP with its paired episode bootstrap
    (:func:`simulation_performance`). With K = 3 the seed level draws from three values only (all
    three alike has probability 1/27 > 2.5 %), so without episode noise ``ci95`` is [min, max] of
    the per-seed SPs: a coarse interval, not a sharp one.

    Args:
        r_stud: (K, E) returns; r_exp, r_0: (E,).
    """
    r_stud, r_exp, r_0 = (np.asarray(r, dtype=np.float64) for r in (r_stud, r_exp, r_0))
    if r_stud.ndim != 2 or r_exp.shape != (r_stud.shape[1],) or r_0.shape != (r_stud.shape[1],):
        raise ValueError(f"returns must be (K, E), (E,), (E,), got {r_stud.shape}, {r_exp.shape}, {r_0.shape}")
    k, e = r_stud.shape
    denom = r_exp.sum() - r_0.sum()
    sp = float((r_stud.sum(1).mean() - r_0.sum()) / denom) if denom != 0 else float("nan")
    ks, es = _resample(k, e, n_boot, seed)
    per_seed = [simulation_performance(r_stud[j], r_exp, r_0, n_boot, seed + 1 + j) for j in range(k)]
    return {"sp": sp, "ci95": _interval(_sp_boot(r_stud, r_exp, r_0, ks, es)), "seeds": k, "episodes": e,
            "per_seed": [{"sp": p["sp"], "ci95": p["ci95"]} for p in per_seed],
            "mean_return": {"student": float(r_stud.mean()), "expert": float(r_exp.mean()),
                            "untrained": float(r_0.mean())}}


def sp_difference(r_a: np.ndarray, r_b: np.ndarray, r_exp: np.ndarray, r_0a: np.ndarray, r_0b: np.ndarray,
                  n_boot: int = 2000, seed: int = 0) -> dict:
    """SP(a) - SP(b) of two settings on the same E episodes, with a 95 % interval that resamples
    each setting's seeds independently (seeds are not paired across settings) and the episodes
    jointly (they are).

    Args:
        r_a: (Ka, E), r_b: (Kb, E) returns; r_exp, r_0a, r_0b (untrained students of a's and b's
            encodings): (E,).
    """
    r_a, r_b, r_exp, r_0a, r_0b = (np.asarray(r, dtype=np.float64) for r in (r_a, r_b, r_exp, r_0a, r_0b))
    e = r_exp.shape[0]
    rng = np.random.default_rng(seed)
    es = rng.integers(0, e, size=(n_boot, e))
    ka = rng.integers(0, r_a.shape[0], size=(n_boot, r_a.shape[0]))
    kb = rng.integers(0, r_b.shape[0], size=(n_boot, r_b.shape[0]))
    boot = _sp_boot(r_a, r_exp, r_0a, ka, es) - _sp_boot(r_b, r_exp, r_0b, kb, es)
    point = sp_over_seeds(r_a, r_exp, r_0a, n_boot=1)["sp"] - sp_over_seeds(r_b, r_exp, r_0b, n_boot=1)["sp"]
    return {"difference": float(point), "ci95": _interval(boot), "episodes": e}


def mse_over_seeds(sq_err: np.ndarray, count: np.ndarray, n_boot: int = 2000, seed: int = 0) -> dict:
    """Test MSE of K students on a test set grouped in E episodes, with the two-level bootstrap
    interval of :func:`sp_over_seeds` (seeds, and episodes with all their windows).

    Args:
        sq_err: (K, E) sum over each episode's windows of the per-window mean squared error (over
            the D outputs); count: (E,) windows per episode.

    Returns:
        {"mse": mean over seeds of sum_e sq_err / sum_e count, "ci95", "per_seed": [MSE_k]}.
    """
    sq_err, count = np.asarray(sq_err, dtype=np.float64), np.asarray(count, dtype=np.float64)
    k, e = sq_err.shape
    per_seed = sq_err.sum(1) / count.sum()
    ks, es = _resample(k, e, n_boot, seed)
    s = sq_err[:, es].sum(-1)  # (K, n_boot)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = s[ks, np.arange(n_boot)[:, None]].mean(1) / count[es].sum(-1)
    return {"mse": float(per_seed.mean()), "ci95": _interval(boot), "per_seed": per_seed.tolist(), "seeds": k,
            "episodes": e, "windows": int(count.sum())}
