"""A cheaper rsl-rl-lib PPO update with the same algorithm, hyper-parameters and mini-batches.

The update is compute-bound: most of its time is the actor's and critic's matrix products, which MKL
already runs near one core's peak (profile in docs/reports/benchmarks.md "PPO update"). What this module removes
is the work rsl-rl adds around them; every change leaves the numbers rsl-rl computes the same, up to the
summation order of fused Adam and threaded products (``tests/learning/test_fast_update.py`` compares
losses, learning rate and weights after one update with the stock one):

* **No second actor pass for the logged mirror loss.** rsl-rl's ``Symmetry.compute_loss`` runs the
  actor again, with autograd recording, on the augmented mini-batch to log the mirror loss even when
  the loss does not train (``use_mirror_loss: false``): a third of the forward matrix products. The
  action means of that pass are the means of the main forward pass a few lines earlier (same
  observations, same weights, the distribution is not touched in between), so
  ``ReusedForwardSymmetry`` takes them from there, without autograd. With ``use_mirror_loss: true``
  the stock loss (with its gradient) is kept.
* **Shuffle once per update.** rsl-rl gathers every mini-batch from the flat rollout with its slice of
  one random permutation (epochs x mini-batches gathers per update). ``ShuffleOnceStorage`` gathers
  the whole rollout with the same permutation once; each mini-batch is then a contiguous slice (a
  view) of it, with the same rows in the same order.
* **Fused Adam** (one kernel over all parameters instead of a ``foreach`` sequence), same defaults.
* **Every core in the update.** Collection keeps the trainer's thread count (the simulator workers
  own the cores then); the update, during which the workers idle, runs with ``threads`` torch
  threads. On a shared machine this needs ``OMP_WAIT_POLICY=PASSIVE`` (the ``learning`` package sets
  it as a default, the Makefile explicitly): with OpenMP's default spin-waiting, extra threads on busy
  cores make the update several times slower than one thread (docs/reports/benchmarks.md "PPO update").

``torch.compile`` of the actor and critic (rsl-rl's agent key ``torch_compile_mode``) is left off: the
time is in MKL's matrix products either way, so it gains little for its compilation at every start
(docs/train.md "Update speed").
"""

from __future__ import annotations

import functools
import os

import torch
import torch.nn.functional as F
from rsl_rl.algorithms import PPO
from rsl_rl.extensions import Symmetry
from rsl_rl.storage import RolloutStorage


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; ``os.cpu_count()`` where unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def default_update_threads() -> int:
    """Threads for one trainer's update: the available cores shared among the processes torchrun
    started on this machine (``LOCAL_WORLD_SIZE``; 1 without torchrun), at least 1."""
    return max(1, available_cores() // int(os.environ.get("LOCAL_WORLD_SIZE", "1")))


class ReusedForwardSymmetry(Symmetry):
    """rsl-rl's ``Symmetry`` whose logged-only mirror loss reuses the update's actor forward pass.

    ``compute_loss`` is called by ``PPO.update`` right after the actor ran on the augmented mini-batch
    (originals then mirrors, ``(2 N, ...)``) with ``stochastic_output=True``, so ``actor.output_mean``
    holds the action means ``mu(o)`` of exactly that batch. The loss is
    ``mse(mu(mirror(o)), mirror(mu(o)))`` over the N mirrored rows, as rsl-rl's.
    """

    def compute_loss(self, actor, batch: RolloutStorage.Batch, original_batch_size: int) -> torch.Tensor:
        if self.use_mirror_loss or not self.use_data_augmentation:
            return super().compute_loss(actor, batch, original_batch_size)  # it trains, or needs its own pass
        with torch.no_grad():
            mean = actor.output_mean  # (2 N, A): mu of originals, then of mirrors
            if mean.shape[0] != batch.observations.batch_size[0]:
                raise RuntimeError(f"actor.output_mean has {mean.shape[0]} rows, the augmented mini-batch "
                                   f"{batch.observations.batch_size[0]}: rsl-rl's update order changed")
            _, mirrored = self.data_augmentation_func(env=self.env, obs=None, actions=mean[:original_batch_size])
            return F.mse_loss(mean[original_batch_size:], mirrored[original_batch_size:])


class ShuffleOnceStorage(RolloutStorage):
    """``RolloutStorage`` whose flat mini-batches are contiguous slices of one shuffled copy.

    Same permutation draw (one ``torch.randperm`` per update, shared by all epochs) and the same rows
    per mini-batch as rsl-rl's generator; one gather per tensor instead of one per mini-batch.
    """

    def mini_batch_generator(self, num_mini_batches: int, num_epochs: int = 8):
        if self.training_type != "rl":
            raise ValueError("mini_batch_generator is for reinforcement learning storage only")
        mini_batch_size = self.num_envs * self.num_transitions_per_env // num_mini_batches
        perm = torch.randperm(num_mini_batches * mini_batch_size, requires_grad=False, device=self.device)

        def shuffled(x):  # (T, E, ...) -> (T E, ...) rows in permutation order
            return x.flatten(0, 1)[perm]

        obs, actions, values, returns = (shuffled(x) for x in (self.observations, self.actions, self.values,
                                                               self.returns))
        log_prob, advantages = shuffled(self.actions_log_prob), shuffled(self.advantages)
        dist_params = tuple(shuffled(p) for p in self.distribution_params)
        for _ in range(num_epochs):
            for i in range(num_mini_batches):
                rows = slice(i * mini_batch_size, (i + 1) * mini_batch_size)
                yield RolloutStorage.Batch(
                    observations=obs[rows], actions=actions[rows], values=values[rows],
                    advantages=advantages[rows], returns=returns[rows], old_actions_log_prob=log_prob[rows],
                    old_distribution_params=tuple(p[rows] for p in dist_params))


def fused_optimizer(optimizer: torch.optim.Optimizer) -> torch.optim.Optimizer:
    """The same optimiser (class, parameters, defaults) with ``fused=True`` where torch has a fused
    kernel for it (Adam, AdamW); others are returned unchanged. Call before the first step."""
    if type(optimizer) not in (torch.optim.Adam, torch.optim.AdamW) or optimizer.state:
        return optimizer
    params = [p for group in optimizer.param_groups for p in group["params"]]
    return type(optimizer)(params, **{**optimizer.defaults, "foreach": False, "fused": True})


def _with_threads(update, threads: int):
    """``update`` run with ``threads`` torch intra-op threads, the caller's count restored after."""

    @functools.wraps(update)
    def update_with_threads(*args, **kwargs):
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return update(*args, **kwargs)
        finally:
            torch.set_num_threads(before)

    return update_with_threads


def speed_up_update(alg: PPO, threads: int | None = None) -> PPO:
    """Make ``alg.update`` cheaper in place (module docstring); call before training or loading a checkpoint.

    Args:
        alg: rsl-rl's ``PPO`` (feed-forward actor and critic; recurrent ones keep rsl-rl's storage).
        threads: torch threads during the update (None: ``default_update_threads()``, every available
            core, shared among torchrun's local processes; 0: leave as is).

    Returns:
        ``alg``.
    """
    if alg.symmetry is not None and type(alg.symmetry) is Symmetry:
        alg.symmetry.__class__ = ReusedForwardSymmetry
    if type(alg.storage) is RolloutStorage and not (alg.actor.is_recurrent or alg.critic.is_recurrent):
        alg.storage.__class__ = ShuffleOnceStorage
    alg.optimizer = fused_optimizer(alg.optimizer)
    threads = default_update_threads() if threads is None else threads
    if threads > 0:
        alg.update = _with_threads(alg.update, threads)
    return alg
