"""The env's episode log: per-step values of the robots that finished an episode, summed on the device and read
back once per PPO iteration (``learning/runner.py``) instead of once per step.

At each policy step the env's reset path gives one 0-dim value per key (``Episode_Reward/<term>``: the mean over
the robots reset at that step of their episode sum / episode length; ``Episode_Termination/<term>``: how many of
them the term ended; ``Episode_Metric/*``, ``Curriculum/*``) and whether any robot reset. :meth:`EpisodeLog.add`
adds the values of steps with resets to a device sum and counts those steps; :meth:`EpisodeLog.read` returns the
mean over them, the number rsl-rl's logger reports when an env hands it one dict per step with resets (it
averages the steps' entries), with one host read.
"""

from __future__ import annotations

import torch


class EpisodeLog:
    """Device sums of per-step episode values and the number of steps with resets that each key saw.

    Args:
        device: where the sums live (the env's device).
    """

    def __init__(self, device: torch.device):
        self.device = torch.device(device)
        self.keys: tuple[str, ...] = ()
        self._sums = torch.zeros(0, dtype=torch.float64, device=self.device)
        self._steps = torch.zeros(0, dtype=torch.float64, device=self.device)
        self._zero = torch.zeros((), dtype=torch.float64, device=self.device)
        self._one = torch.ones((), dtype=torch.float64, device=self.device)

    def add(self, values: dict[str, torch.Tensor], any_reset: torch.Tensor) -> None:
        """Add one step's 0-dim ``values`` (tensors on the device) where ``any_reset`` (0-dim bool) holds; no host
        read, no upload. A key not seen before starts at zero (its mean covers the steps from then on)."""
        if not all(k in self.keys for k in values):
            self._extend(tuple(values))
        step = any_reset.to(torch.float64)
        stacked = torch.stack([values.get(k, self._zero) for k in self.keys]).to(torch.float64)
        self._sums += torch.where(any_reset, stacked, 0.0)
        if len(values) == len(self.keys):
            self._steps += step
        else:  # a key missing at this step: its step count stays
            self._steps += torch.stack([self._one if k in values else self._zero for k in self.keys]) * step

    def _extend(self, keys: tuple[str, ...]) -> None:
        new = [k for k in keys if k not in self.keys]
        if new:
            self.keys = (*self.keys, *new)
            # normal tensors even under inference mode (rsl-rl's rollouts): summed into in place in and out of it
            with torch.inference_mode(False):
                pad = torch.zeros(len(new), dtype=torch.float64, device=self.device)
                self._sums = torch.cat([self._sums, pad])
                self._steps = torch.cat([self._steps, pad])

    def read(self) -> dict[str, float]:
        """``{key: mean over the steps with resets since the last read}`` (keys without such steps are left out),
        with one host read; the sums start again from zero."""
        if not self.keys:
            return {}
        sums, steps = torch.stack([self._sums, self._steps]).tolist()
        self._sums.zero_()
        self._steps.zero_()
        return {k: s / n for k, s, n in zip(self.keys, sums, steps) if n > 0}
