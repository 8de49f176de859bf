"""The sampling MPC's trajectory cost of a horizon action, as a reward term (thesis 5.3).

Each policy step, every robot's horizon action (``actions.horizon``: the encoded horizon the policy output, kept by
the action manager with the state and command it was chosen at) is rolled out by the MPC's SRBD model from that
state and scored by the MPC's state cost (``mpc.horizon.score_horizon``: the functions, weights and references of
``SamplingMPC``; one rollout per robot, batched). The term's value is the normalised cost

    c = min(J_state / J_ref, clip),   J_state = sum_{k=0}^{N-1} (x_{k+1} - x_ref)^T Q (x_{k+1} - x_ref),

a non-finite J counting as ``clip``. ``J_ref`` is a fixed reference cost, the state rollout cost of the naive warm
start's chosen plan on Table 14's protocol (docs/experiments/mpc_cost_plan.md), so c ~ 1 for a plan as good as the
MPC's own after its 10 000 samples; the DAgger student's horizon, unoptimised, scores c ~ 10. A fixed J_ref keeps the
reward stationary (a running normaliser would rescale it as the policy improves, and make the weights of an ablation
mean different things in different runs). ``clip`` bounds what one step can cost a falling robot (its height term
alone reaches c ~ 500), which would otherwise swamp the value function.

The value comes from the controller's cost kernel (``cpp`` on the CPU: ~1 ms for 256 robots). The split by term
(``mpc.horizon.TERM_NAMES``: z, vx, vy, vz, roll, pitch and the three rates) needs the eager reference rollout (~6 ms
for 256 robots), so it is computed every ``split_every``-th call (1: every call); each robot's parts are its value
times its shares of the latest split, so they sum to the value and the reward manager logs them (``parts``). The
kernel computes on the CPU, so with the env on a GPU each step copies the horizons and states to the host and the
values back (not measured on a GPU).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import torch

from dls_quadruped.mpc import horizon as mpc_horizon


@dataclass
class _Split:
    """Per env: calls so far, each robot's shares of the terms (B, 9) from the latest split, the last parts (B, 9)."""

    calls: int
    shares: torch.Tensor
    parts: torch.Tensor


_SPLITS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def check_params(reference_cost: float, com_height: float, clip: float, split_every: int) -> None:
    """Raise ValueError naming a parameter outside its range."""
    if not 0 < reference_cost < float("inf"):
        raise ValueError(f"mpc_trajectory_cost: reference_cost must be > 0 and finite (a state rollout cost, "
                         f"Table 14's naive plan ~200), got {reference_cost!r}")
    if not 0.1 <= com_height <= 0.6:
        raise ValueError(f"mpc_trajectory_cost: com_height (the MPC's CoM height reference) must be in [0.1, 0.6] m, "
                         f"got {com_height!r}")
    if not 0 < clip < float("inf"):
        raise ValueError(f"mpc_trajectory_cost: clip must be > 0 and finite (multiples of reference_cost), "
                         f"got {clip!r}")
    if isinstance(split_every, bool) or not isinstance(split_every, int) or split_every < 1:
        raise ValueError(f"mpc_trajectory_cost: split_every must be an int >= 1 (1: the split by term on every call), "
                         f"got {split_every!r}")


def trajectory_cost(env, reference_cost: float, com_height: float, clip: float, split_every: int) -> torch.Tensor:
    """(B,) normalised MPC state cost of each robot's horizon action (see the module docstring).

    Raises:
        ValueError: the task has no ``actions.horizon`` (nothing to roll out), or a parameter is out of range.
    """
    check_params(reference_cost, com_height, clip, split_every)
    am = env.action_manager
    if getattr(am, "horizon", None) is None:
        raise ValueError("mpc_trajectory_cost scores a horizon action: the task needs actions.horizon "
                         "(e.g. {p: first, F: spline, horizon: 10, dt: 0.02}, tasks/base_mpc_cost.yaml)")
    state = am.decision_state if am.decision_state is not None else env.state
    cfg = mpc_horizon.horizon_sampler_config(am.horizon, am.horizon_dt, am.cfg)
    split = _SPLITS.get(env)
    if split is None or split.shares.shape[0] != am.raw_horizon.shape[0]:
        b = am.raw_horizon.shape[0]
        split = _SPLITS[env] = _Split(0, torch.full((b, len(mpc_horizon.TERM_NAMES)), float("nan")), torch.zeros(0))
    score = mpc_horizon.score_horizon(am.raw_horizon, state, am.decision_command, com_height, cfg,
                                      terms=split.calls % split_every == 0)
    split.calls += 1
    total = score.state_cost / reference_cost
    finite = torch.isfinite(total)
    value = torch.where(finite, total.clamp(max=clip), torch.full_like(total, clip))
    if score.state_terms is not None:
        sums = score.state_terms.sum(-1, keepdim=True)
        split.shares = torch.where(torch.isfinite(sums) & (sums > 0), score.state_terms / sums, split.shares)
    split.parts = torch.nan_to_num(value[:, None] * split.shares, nan=0.0).to(env.device)
    return value.to(env.device)


def parts(env) -> dict[str, torch.Tensor]:
    """The last :func:`trajectory_cost` of ``env`` by term: name -> (B,), its value times the robot's shares of the
    latest split (summing to the value; 0 for a robot with no finite split yet); empty before the first call."""
    split = _SPLITS.get(env)
    if split is None or split.parts.numel() == 0:
        return {}
    return {name: split.parts[:, i] for i, name in enumerate(mpc_horizon.TERM_NAMES)}
