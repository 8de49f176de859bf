"""What a closed-loop controller runs with (``ControllerConfig``), and which controllers need what.

A config names a controller of ``CONTROLLER_REGISTRY`` (``closed_loop/registry.py``; ``closed_loop/controllers.py``
registers the built-in ones when it is imported), its networks, the sampling MPC's settings and the MPC's gait
and references. In an env the MPC's latent-action configuration is the env's (:meth:`ControllerConfig.for_env`):
the action is configured once, in the task's ``actions.latent``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from dls_quadruped.closed_loop.registry import CONTROLLER_REGISTRY
from dls_quadruped.control.latent_action import LatentActionConfig
from dls_quadruped.mpc.baseline import BaselineConfig, check_optimise
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.inputs import GROUNDS
from dls_quadruped.mpc.warm_start import check_shares

NEEDS_STUDENT = ("rl_warm_start", "student", "rl_gait_naive_forces", "naive_gait_rl_forces")
"""The controllers that query a distilled student."""
NEEDS_POLICY = ("rl_baseline",)
"""The controllers that query the RL expert."""
MPC_CONTROLLERS = ("rl_warm_start", "naive_warm_start", "rl_gait_naive_forces", "naive_gait_rl_forces")
"""The controllers that run the sampling MPC (its settings and sampler seeds apply to them)."""


@dataclass(frozen=True)
class ControllerConfig:
    """What to run.

    Attributes:
        name: one of ``CONTROLLERS`` (``closed_loop/registry.py``).
        policy: the RL expert (an exported actor, ``learning.policy_file``, or an rsl-rl checkpoint), for
            ``rl_baseline``.
        student: a distilled student export (``make distill``), for ``rl_warm_start`` and ``student``;
            for ``rl_warm_start`` also a tuple of exports (several policies warm-start one MPC).
        shares: ``rl_warm_start`` with several students: each student group's share of the samples that
            are not the naive group's (positive, summing to 1); None = equal shares.
        sampler: MPC settings (M, N, dt, encoding, kernel, sigmas); the student must match its
            encoding, horizon and dt. Its ``action`` is left at the default: in an env the env's applies
            (:meth:`for_env`).
        optimise: variables the MPC samples (sigma of the others set to 0): default forces only.
        naive_share: ``rl_warm_start`` only: share of the M samples drawn around the naive warm start
            (previous solution shifted), the rest around the student's horizon; 0 = student only.
        seed: seed of the MPC's noise.
        horizon_cost_every: record the chosen sample's cost per horizon step (Fig. 28) at every k-th solve
            (an eager re-rollout, ~1.5 ms per solve).
        ground: MPC controllers: the ground the MPC plans on, one of ``mpc.inputs.GROUNDS`` (``terrain``: the
            env's map).
        naive_gait: ``naive_warm_start`` only: its trot's (frequency [Hz], duty), else ``BaselineConfig``'s.
        com_height: the CoM height reference [m] above the ground of an MPC controller's cost and of every
            controller's initial-cost metric, else ``BaselineConfig``'s.
        anchor_share: ``naive_warm_start`` only: ``BaselineConfig.anchor_share``, the share of the samples drawn
            around the nominal trot besides the naive warm start (0: the thesis's naive controller).
    """

    name: str
    policy: Path | None = None
    student: Path | tuple[Path, ...] | None = None
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    optimise: tuple[str, ...] = ("F",)
    naive_share: float = 0.0
    shares: tuple[float, ...] | None = None
    seed: int = 0
    horizon_cost_every: int = 10
    ground: str = "flat"
    naive_gait: tuple[float, float] | None = None
    com_height: float | None = None
    anchor_share: float = 0.0

    def __post_init__(self) -> None:
        CONTROLLER_REGISTRY.check(self.name)
        if self.name in NEEDS_STUDENT and not self.students:
            raise ValueError(f"controller {self.name!r} needs a student (--student, a `make distill` export)")
        if self.name in NEEDS_POLICY and self.policy is None:
            raise ValueError(f"controller {self.name!r} needs the RL expert (--policy)")
        check_optimise(self.optimise)
        if not 0.0 <= self.naive_share < 1.0:
            raise ValueError(f"naive_share must be in [0, 1), got {self.naive_share!r}")
        if not isinstance(self.horizon_cost_every, int) or self.horizon_cost_every < 1:
            raise ValueError(f"horizon_cost_every must be an int >= 1, got {self.horizon_cost_every!r}")
        if self.naive_share > 0.0 and self.name != "rl_warm_start":
            raise ValueError(f"naive_share applies to rl_warm_start only, got it for {self.name!r}")
        if len(self.students) > 1 and self.name != "rl_warm_start":
            raise ValueError(f"several students warm-start rl_warm_start only; {self.name!r} takes one, "
                             f"got {len(self.students)}")
        if self.shares is not None:
            check_shares(self.shares, len(self.students))
        if self.ground not in GROUNDS:
            raise ValueError(f"ground must be one of {list(GROUNDS)}, got {self.ground!r}")
        if self.naive_gait is not None and self.name != "naive_warm_start":
            raise ValueError(f"naive_gait applies to naive_warm_start only, got it for {self.name!r}")
        if self.anchor_share != 0.0 and self.name != "naive_warm_start":
            raise ValueError(f"anchor_share applies to naive_warm_start only, got it for {self.name!r}")
        self.baseline_config()  # checks the gait and the height reference

    def baseline_config(self) -> BaselineConfig:
        """The MPC's gait and references (``BaselineConfig``) with ``naive_gait``, ``com_height`` and
        ``anchor_share`` applied."""
        kw = {} if self.naive_gait is None else {"freq": float(self.naive_gait[0]), "duty": float(self.naive_gait[1])}
        kw.update({} if self.com_height is None else {"com_height": float(self.com_height)})
        return BaselineConfig(optimise=self.optimise, sampler=self.sampler, anchor_share=self.anchor_share, **kw)

    @classmethod
    def naive(cls, baseline: BaselineConfig, seed: int = 0) -> ControllerConfig:
        """``naive_warm_start`` running ``baseline`` (its :meth:`baseline_config` is ``baseline``) with noise seed
        ``seed``."""
        return cls("naive_warm_start", sampler=baseline.sampler, optimise=baseline.optimise, seed=seed,
                   naive_gait=(baseline.freq, baseline.duty), com_height=baseline.com_height,
                   anchor_share=baseline.anchor_share)

    @property
    def students(self) -> tuple[Path, ...]:
        """The student exports, in group order (empty without a student)."""
        if self.student is None:
            return ()
        if isinstance(self.student, (tuple, list)):
            return tuple(Path(s) for s in self.student)
        return (Path(self.student),)

    def group_shares(self) -> tuple[float, ...]:
        """``rl_warm_start``: the share of the M samples of every group, students first, then the naive
        group if ``naive_share`` > 0."""
        n = len(self.students)
        shares = self.shares if self.shares is not None else (1.0 / n,) * n
        out = tuple((1.0 - self.naive_share) * s for s in shares)
        return out + ((self.naive_share,) if self.naive_share > 0.0 else ())

    @property
    def uses_mpc(self) -> bool:
        return self.name in MPC_CONTROLLERS

    def for_env(self, env) -> ControllerConfig:
        """This config acting in ``env``: the MPC's latent-action configuration (``sampler.action``: Table 5's
        normalisation, Table 1's limits, mass, mu, nominal footholds) becomes the env's (``env.action_manager.cfg``,
        the task's ``actions.latent``), so the MPC encodes its solutions into raw actions exactly as the env decodes
        them, and a ``--set actions.latent.<field>=...`` reaches both. Outside an env (library use, the benches) the
        MPC keeps ``sampler.action``.

        Raises:
            ValueError: ``sampler.action`` was set to something other than both the default and the env's.
        """
        own, env_action = self.sampler.action, env.action_manager.cfg
        if own == env_action:
            return self
        if own != LatentActionConfig():
            differ = ", ".join(f"{f.name} (sampler {getattr(own, f.name)!r}, env {getattr(env_action, f.name)!r})"
                               for f in fields(own) if getattr(own, f.name) != getattr(env_action, f.name))
            raise ValueError(f"the MPC's sampler.action differs from the env's action configuration (the task's "
                             f"actions.latent) in {differ}; configure the latent action once, in the task "
                             f"(--set actions.latent.<field>=...), and leave sampler.action at its default")
        return replace(self, sampler=replace(self.sampler, action=env_action))
