"""Left-right mirror symmetry of the policy observation and the latent action.

The mirror is the reflection about the base's x-z plane (y -> -y): left and right legs swap
(FL <-> FR, RL <-> RR), lateral components of polar vectors change sign (v_y, g_y, p_y, F_y), and
the x and z components of axial vectors change sign (roll and yaw rates), as do hip-abduction
angles (their joint axis is the base x axis).

Each observation term is mirrored by one function of its values, keyed by the term's function
name in ``envs/mdp/observations.py``; the group vector is mirrored term by term in the order the
task file lists the terms, so a task that reorders or drops terms still mirrors correctly. Every
term mirror is a signed permutation, checked when the maps are built: it must keep the shape and
be an involution (mirroring twice gives the input back), or a ``SymmetryError`` names the term.

rsl-rl-lib 5's ``Symmetry`` extension calls the augmentation function as
``fn(env=env, obs=TensorDict | None, actions=Tensor | None)`` and expects the originals followed
by their mirrors, ``(2 N, ...)`` each (``None`` stays ``None``). The agent YAML selects it::

    algorithm:
      symmetry_cfg:
        data_augmentation_func: dls_quadruped.learning.symmetry:mirror_augmentation
        use_data_augmentation: true     # append mirrored samples to every mini-batch
        use_mirror_loss: false          # or: MSE between pi(mirror(obs)) and mirror(pi(obs))
        mirror_loss_coeff: 0.0
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.height_scan import HeightScanConfig

MirrorFn = Callable[[torch.Tensor], torch.Tensor]
"""Mirror of one term: (N, D) -> (N, D)."""

LEG_MIRROR = (1, 0, 3, 2)
"""Leg index of each leg's mirror image, in the order FL, FR, RL, RR."""
assert tuple(C.LEG_NAMES[i] for i in LEG_MIRROR) == ("FR", "FL", "RR", "RL")

HIP = 0
"""Index of the hip-abduction joint within a leg's (hip, thigh, calf)."""


class SymmetryError(ValueError):
    """A mirror map that changes the shape of a term or is not an involution."""


# ------------------------------------------------------------------ signed permutations
def _negate(components: tuple[int, ...]) -> MirrorFn:
    """Negate the listed components of a vector term."""

    def mirror(x: torch.Tensor) -> torch.Tensor:
        sign = torch.ones(x.shape[-1], dtype=x.dtype, device=x.device)
        sign[list(components)] = -1.0
        return x * sign

    return mirror


def swap_legs(x: torch.Tensor, per_leg: int = 1) -> torch.Tensor:
    """(N, 4 * per_leg) leg-major values with FL <-> FR and RL <-> RR swapped."""
    return x.reshape(*x.shape[:-1], C.NUM_LEGS, per_leg)[..., list(LEG_MIRROR), :].reshape(x.shape)


def mirror_joints(x: torch.Tensor) -> torch.Tensor:
    """(N, 12) joint values (positions relative to the nominal pose, whose hip angle is 0, or
    velocities), leg-major (hip, thigh, calf): legs swapped, hip abduction negated."""
    sign = torch.ones(C.JOINTS_PER_LEG, dtype=x.dtype, device=x.device)
    sign[HIP] = -1.0
    legs = swap_legs(x, C.JOINTS_PER_LEG).reshape(*x.shape[:-1], C.NUM_LEGS, C.JOINTS_PER_LEG)
    return (legs * sign).reshape(x.shape)


def mirror_action(a: torch.Tensor) -> torch.Tensor:
    """(N, 28) raw latent action [f(4) | d(4) | p_xy(4 x 2) | F_xyz(4 x 3)], frame H, legs swapped
    and p_y, F_y negated. Exact in network units because every shift and clip range is
    left-right symmetric (p and F_y have zero shift, the nominal footholds mirror each other)."""
    f, d = swap_legs(a[..., 0:4]), swap_legs(a[..., 4:8])
    p = swap_legs(a[..., 8:16], 2) * torch.tensor([1.0, -1.0], dtype=a.dtype, device=a.device).repeat(C.NUM_LEGS)
    F = swap_legs(a[..., 16:28], 3) * torch.tensor([1.0, -1.0, 1.0], dtype=a.dtype, device=a.device).repeat(C.NUM_LEGS)
    return torch.cat([f, d, p, F], dim=-1)


_SCAN = HeightScanConfig()


def mirror_height_scan(x: torch.Tensor, cfg: HeightScanConfig = _SCAN) -> torch.Tensor:
    """(N, ny * nx) scan, index iy * nx + ix with iy = 0 on the right: rows iy <-> ny - 1 - iy."""
    nx, ny = cfg.shape
    return x.reshape(*x.shape[:-1], ny, nx).flip(-2).reshape(x.shape)


OBSERVATION_MIRRORS: dict[str, MirrorFn] = {
    "base_lin_vel": _negate((1,)),                   # v_y
    "base_ang_vel": _negate((0, 2)),                 # axial: roll and yaw rates
    "projected_gravity": _negate((1,)),              # g_y
    "joint_pos": mirror_joints,
    "joint_vel": mirror_joints,
    "last_action": mirror_action,
    "leg_phase": swap_legs,
    "foot_contact": swap_legs,
    "height_scan": mirror_height_scan,
    "velocity_command": _negate((1, 2)),             # v_y, omega_z
}
"""Mirror of each observation term, keyed by its function name in ``envs/mdp/observations.py``."""


# ------------------------------------------------------------------ checked maps
def check_mirror(name: str, fn: MirrorFn, dim: int, num_probe: int = 4, seed: int = 0) -> None:
    """Raise ``SymmetryError`` naming ``name`` if ``fn`` changes the shape of (num_probe, dim)
    random values or is not an involution on them (mirror(mirror(x)) != x)."""
    x = torch.randn(num_probe, dim, generator=torch.Generator().manual_seed(seed))
    try:
        y = fn(x)
    except Exception as err:  # a map written for another size fails here with the term's name
        raise SymmetryError(f"mirror of term {name!r} fails on input of shape {tuple(x.shape)}: {err!r}") from err
    if not isinstance(y, torch.Tensor) or y.shape != x.shape:
        shape = tuple(y.shape) if isinstance(y, torch.Tensor) else type(y).__name__
        raise SymmetryError(f"mirror of term {name!r} maps shape {tuple(x.shape)} to {shape}; it must keep the shape")
    back = fn(y)
    if not torch.allclose(back, x, atol=1e-6, rtol=0.0):
        err = float((back - x).abs().max())
        raise SymmetryError(f"mirror of term {name!r} is not an involution: |mirror(mirror(x)) - x| up to {err:.3g}")


@dataclass(frozen=True)
class GroupMirror:
    """Mirror of one observation group: term mirrors applied to consecutive slices.

    Attributes:
        terms: (term name, start, stop, mirror) in the group's order.
        dim: total size of the group vector.
    """

    terms: tuple[tuple[str, int, int, MirrorFn], ...]
    dim: int

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] != self.dim:
            raise SymmetryError(f"observation has {x.shape[-1]} values, the mirror map expects {self.dim}")
        return torch.cat([fn(x[..., a:b]) for _, a, b, fn in self.terms], dim=-1)


def group_mirror(group: str, terms: list[tuple[str, str, int]],
                 mirrors: dict[str, MirrorFn] | None = None) -> GroupMirror:
    """Checked mirror of an observation group.

    Args:
        group: group name (for error messages).
        terms: (term name, function name, dim) in the group's order.
        mirrors: function name -> mirror (default ``OBSERVATION_MIRRORS``).
    """
    mirrors = OBSERVATION_MIRRORS if mirrors is None else mirrors
    parts, start = [], 0
    for name, func, dim in terms:
        label = f"observations.{group}.{name} ({func})"
        if func not in mirrors:
            raise SymmetryError(f"no mirror for term {label!r}; terms with a mirror: {sorted(mirrors)}")
        check_mirror(label, mirrors[func], dim)
        parts.append((name, start, start + dim, mirrors[func]))
        start += dim
    return GroupMirror(tuple(parts), start)


@dataclass(frozen=True)
class EnvMirror:
    """Checked mirrors of every observation group and of the action of one env."""

    groups: dict[str, GroupMirror]
    action: MirrorFn

    def observations(self, obs: TensorDict) -> TensorDict:
        return TensorDict({g: self.groups[g](v) for g, v in obs.items()}, batch_size=obs.batch_size, device=obs.device)


def env_mirror(env, action_mirror: MirrorFn = mirror_action, mirrors: dict[str, MirrorFn] | None = None) -> EnvMirror:
    """Build and check the mirror maps of ``env`` (a ``LocomotionEnv``) from its observation terms."""
    om = env.observation_manager
    obs = env.get_observations()
    groups = {}
    for group, terms in om.groups.items():
        dims = om.dims.get(group) or {t.name: t(env).reshape(env.num_envs, -1).shape[1] for t in terms}
        groups[group] = group_mirror(group, [(t.name, t.func.__name__, dims[t.name]) for t in terms], mirrors)
        if groups[group].dim != obs[group].shape[-1]:
            raise SymmetryError(f"observation group {group!r} has {obs[group].shape[-1]} values, "
                                f"its terms add up to {groups[group].dim}")
    check_mirror("actions (latent action)", action_mirror, env.num_actions)
    return EnvMirror(groups, action_mirror)


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def mirror_for(env) -> EnvMirror:
    """The env's checked mirror maps, built once per env object."""
    if env not in _CACHE:
        _CACHE[env] = env_mirror(env)
    return _CACHE[env]


def mirror_augmentation(env, obs: TensorDict | None = None, actions: torch.Tensor | None = None
                        ) -> tuple[TensorDict | None, torch.Tensor | None]:
    """rsl-rl ``Symmetry`` augmentation: originals followed by their mirrors.

    Args:
        env: the ``LocomotionEnv`` (its observation terms define the layout).
        obs: TensorDict {group: (N, D)} or None.
        actions: (N, 28) raw latent actions or None.

    Returns:
        (TensorDict {group: (2 N, D)} or None, (2 N, 28) or None).
    """
    m = mirror_for(env)
    obs_aug = None
    if obs is not None:
        obs_aug = torch.cat([obs, m.observations(obs)], dim=0)
    act_aug = None if actions is None else torch.cat([actions, m.action(actions)], dim=0)
    return obs_aug, act_aug


def check_symmetry_cfg(env, train_cfg: dict) -> None:
    """Start-up check of ``train_cfg["algorithm"]["symmetry_cfg"]`` (if any): its function resolves,
    the env's mirror maps keep the shapes and are involutions, and the augmentation doubles the
    batch with the mirrors last. Raises ``SymmetryError`` naming the offending term."""
    from rsl_rl.utils import resolve_callable

    sym = (train_cfg.get("algorithm") or {}).get("symmetry_cfg")
    if not sym:
        return
    fn = resolve_callable(sym["data_augmentation_func"])
    if fn is mirror_augmentation:
        mirror_for(env)  # builds and checks every term map
    obs = env.get_observations()[:2]
    n = obs.batch_size[0]
    act = torch.randn(n, env.num_actions, device=env.device)
    obs_aug, act_aug = fn(env=env, obs=obs, actions=act)
    name = sym["data_augmentation_func"]
    for group in obs.keys():  # noqa: SIM118 (TensorDict keys)
        want = (2 * n, obs[group].shape[-1])
        if tuple(obs_aug[group].shape) != want:
            raise SymmetryError(f"symmetry function {name!r}: observation group {group!r} of shape "
                                f"{tuple(obs[group].shape)} became {tuple(obs_aug[group].shape)}; "
                                f"expected (2 N, D) = {want}")
    if tuple(act_aug.shape) != (2 * n, env.num_actions):
        raise SymmetryError(f"symmetry function {name!r}: actions of shape {tuple(act.shape)} became "
                            f"{tuple(act_aug.shape)}; expected {(2 * n, env.num_actions)}")

