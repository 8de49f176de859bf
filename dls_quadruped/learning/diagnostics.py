"""Per-iteration PPO diagnostics: exploration std, clipping, ignored action components, learning rate, KL.

What is logged (TensorBoard tags ``Diagnostics/<name>``; ``docs/train.md`` "Diagnostics" says how to read them),
the groups ``g`` being the latent action's components f, d, p, F (``control/latent_action.py``):

* ``std_<g>``: the policy's action std after the update, mean over the group's dimensions (raw units);
  ``std_<component>`` per dimension, e.g. ``std_F_z_RL``;
* ``clip_frac_<g>``, ``clip_frac``: fraction of the rollout's sampled (step, robot, dimension) entries that the
  action interface's clip (Table 1 ranges, friction cone) changed;
* ``outside_unit_frac_<g>``: fraction of the sampled raw entries with |a| > 1, outside the range the
  normalisation's scales map to typical values (the raw action itself is not clipped to [-1, 1]);
* ``F_ignored_frac`` / ``p_ignored_frac``: fraction of the rollout's (physics step, robot, leg) triples in which
  that leg was in swing (its force F did not act) / in stance (its foothold p did not act on the torques);
* ``learning_rate``: the learning rate after the update (rsl-rl's adaptive schedule);
* ``kl_mean`` / ``kl_max``: mean and max over the update's mini-batches of the mean KL(old || new) rsl-rl's
  adaptive schedule computes (this rank's; absent with a fixed schedule, where rsl-rl computes none).

Everything comes from tensors the iteration has anyway: the action manager's per-step clip mask and stance
fractions, the rollout storage's sampled actions (read before the update clears it), the KL rsl-rl computes
(recorded by wrapping the actor's ``get_kl_divergence``) and the distribution's std. No extra forward pass.
"""

from __future__ import annotations

import functools

import torch

from dls_quadruped.control.latent_action import (
    ACTION_COMPONENT_NAMES,
    ACTION_DIM,
    ACTION_GROUPS,
)


def group_means(x: torch.Tensor) -> dict[str, torch.Tensor]:
    """Mean of a (..., 28) latent-action tensor over each component group: {"f", "d", "p", "F"} -> (...)."""
    return {name: x[..., rows].mean(dim=-1) for name, rows in ACTION_GROUPS}


def outside_unit_fraction(actions: torch.Tensor) -> torch.Tensor:
    """Fraction of sampled raw actions with |a| > 1, per dimension.

    Args:
        actions: (T, E, A) or (N, A) raw actions (network units).

    Returns:
        (A,) in [0, 1].
    """
    return (actions.abs() > 1.0).flatten(0, -2).to(torch.float32).mean(dim=0)


def ignored_fractions(stance_frac: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Fractions of (physics step, robot, leg) in which F (leg in swing) and p (leg in stance) were ignored.

    Args:
        stance_frac: (..., 4) fraction of each action's physics steps each leg spent in stance.

    Returns:
        (F_ignored, p_ignored): 0-dim tensors in [0, 1] that sum to 1.
    """
    p_ignored = stance_frac.to(torch.float32).mean()
    return 1.0 - p_ignored, p_ignored


def _tag_name(component: str) -> str:
    """``"F_z[RL]"`` -> ``"F_z_RL"`` (TensorBoard tags allow no brackets)."""
    return component.replace("[", "_").replace("]", "")


class TrainingDiagnostics:
    """Collects the diagnostics of one PPO iteration from an rsl-rl ``OnPolicyRunner`` (module docstring).

    ``attach`` wraps the algorithm's ``process_env_step`` and ``update`` and the actor's ``get_kl_divergence``
    in place; ``scalars()`` returns the iteration's values and starts the next iteration's.
    """

    def __init__(self, env, alg):
        self.env, self.alg = env, alg
        self.latent = int(env.num_actions) == ACTION_DIM  # groups and names need the latent action's layout
        self.manager = getattr(env, "action_manager", None)
        if self.manager is not None and not hasattr(self.manager, "stance_frac"):
            self.manager = None
        self._kl: list[torch.Tensor] = []
        self._outside: torch.Tensor | None = None
        self._clipped: torch.Tensor | None = None  # (A,) count of clipped entries over the rollout
        self._stance: torch.Tensor | None = None  # () sum over the rollout's steps of the mean stance fraction
        self._steps = 0
        self._robots = 0

    @classmethod
    def attach(cls, runner) -> TrainingDiagnostics:
        """Hook a new collector into ``runner.alg`` (call after any other wrapping of ``alg.update``)."""
        diag = cls(runner.env, runner.alg)
        alg = runner.alg
        alg.process_env_step = diag._wrap_step(alg.process_env_step)
        alg.update = diag._wrap_update(alg.update)
        actor = alg.get_policy()  # a compiled actor forwards the attribute to this module
        actor.get_kl_divergence = diag._wrap_kl(actor.get_kl_divergence)
        return diag

    # ------------------------------------------------------------------ hooks
    def _wrap_step(self, process_env_step):
        @functools.wraps(process_env_step)
        def recording(*args, **kwargs):
            if self.manager is not None:  # the action manager holds this step's action's clip mask and contacts
                clipped = self.manager.saturated.sum(dim=0)
                stance = self.manager.stance_frac.mean()
                self._clipped = clipped if self._clipped is None else self._clipped + clipped
                self._stance = stance if self._stance is None else self._stance + stance
                self._steps += 1
                self._robots = self.manager.saturated.shape[0]
            return process_env_step(*args, **kwargs)

        return recording

    def _wrap_update(self, update):
        @functools.wraps(update)
        def recording(*args, **kwargs):
            storage = self.alg.storage  # its actions are the rollout's samples until the update clears it
            self._outside = outside_unit_fraction(storage.actions)
            self._kl.clear()
            return update(*args, **kwargs)

        return recording

    def _wrap_kl(self, get_kl_divergence):
        @functools.wraps(get_kl_divergence)
        def recording(old_params, new_params):
            kl = get_kl_divergence(old_params, new_params)  # (N,) per sample
            self._kl.append(kl.mean().detach())
            return kl

        return recording

    # ------------------------------------------------------------------ values
    def scalars(self) -> dict[str, float]:
        """This iteration's values, keyed by name (tag ``Diagnostics/<name>``); resets the rollout's sums."""
        values: dict[str, torch.Tensor] = {}
        std = self.alg.get_policy().output_std.detach()
        std = std.reshape(-1, std.shape[-1]).mean(dim=0)  # (A,): the same in every row for a learned std
        if self._kl:
            kl = torch.stack(self._kl)
            values.update(kl_mean=kl.mean(), kl_max=kl.max())
        if self._stance is not None:
            values["F_ignored_frac"], values["p_ignored_frac"] = ignored_fractions(self._stance / self._steps)
        if self.latent:
            values.update({f"std_{g}": v for g, v in group_means(std).items()})
            values.update({f"std_{_tag_name(c)}": std[i] for i, c in enumerate(ACTION_COMPONENT_NAMES)})
            if self._clipped is not None:
                frac = self._clipped.to(torch.float32) / (self._steps * self._robots)  # (A,)
                values["clip_frac"] = frac.mean()
                values.update({f"clip_frac_{g}": v for g, v in group_means(frac).items()})
            if self._outside is not None:
                values.update({f"outside_unit_frac_{g}": v for g, v in group_means(self._outside).items()})
        self._kl.clear()
        self._outside = self._clipped = self._stance = None
        self._steps = 0
        names = list(values)
        # stacked where they live, then one device-to-host read
        numbers = torch.stack([values[k].to(std.device, torch.float32).reshape(()) for k in names]).tolist()
        return {"learning_rate": float(self.alg.learning_rate), **dict(zip(names, numbers))}

    @staticmethod
    def summary(values: dict[str, float]) -> str:
        """One console line of the iteration's main diagnostics."""
        groups = [g for g, _ in ACTION_GROUPS]

        def per_group(prefix: str) -> str:
            return " ".join(f"{g} {values[f'{prefix}_{g}']:.2f}" for g in groups if f"{prefix}_{g}" in values)

        parts = [f"lr {values['learning_rate']:.2e}"]
        if "kl_mean" in values:
            parts.append(f"kl {values['kl_mean']:.4f} (max {values['kl_max']:.4f})")
        parts += [f"std [{per_group('std')}]", f"clip [{per_group('clip_frac')}]"]
        if "F_ignored_frac" in values:
            parts.append(f"ignored F {values['F_ignored_frac']:.2f} p {values['p_ignored_frac']:.2f}")
        return "[diag] " + "  ".join(parts)
