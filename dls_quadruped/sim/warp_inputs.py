"""The Warp backend's input checks: host values checked on the host, device values on the device.

A value given on the host (lists, arrays, CPU tensors for a CUDA backend) is checked before it is uploaded
and raises at once. A value already on the backend's device (the env's own tensors) is checked there without
a host read: an invalid one sets a 0-d bool flag, which the backend reads once every ``check_every`` step
calls (``WarpSim.check_inputs``); out-of-range row ids are clamped meanwhile, so no write lands outside the
batch.
"""

from __future__ import annotations

from typing import Any

import torch

REFERENCES = ("freq", "duty", "p_td_w", "F_w")
"""The latent references, flagged together (:attr:`DeviceInputs.bad_refs`)."""


class DeviceInputs:
    """Input checks of a backend of ``num_envs`` robots on ``device``, with their pending flags.

    Args:
        num_envs: number of robots N (row ids are in [0, N)).
        device: the backend's device.
    """

    def __init__(self, num_envs: int, device: torch.device):
        self.num_envs = num_envs
        self.device = device
        self.bad_refs = torch.zeros(len(REFERENCES), dtype=torch.bool, device=device)
        """Non-finite freq, duty, p_td_w, F_w seen (in :data:`REFERENCES` order)."""
        self.bad_inputs: dict[str, torch.Tensor] = {}
        """Other inputs checked on the device (:meth:`ids`, :meth:`rows`), by name."""

    def ids(self, env_ids: Any) -> torch.Tensor:
        """Row ids as a long tensor on the device. Ids given on the host are range-checked there; ids already on
        the device are checked on the device without a host read: out-of-range ones are clamped and flagged."""
        if isinstance(env_ids, torch.Tensor) and env_ids.device == self.device and not env_ids.is_floating_point():
            ids = env_ids.reshape(-1).long()
            bad = (ids < 0) | (ids >= self.num_envs)
            self.flag("env_ids").logical_or_(bad.any())
            return ids.clamp(0, self.num_envs - 1)
        host = torch.as_tensor(env_ids).reshape(-1).cpu().long()
        if len(host) and (int(host.min()) < 0 or int(host.max()) >= self.num_envs):
            raise ValueError(f"env_ids must be in [0, {self.num_envs}), got min {int(host.min())} "
                             f"max {int(host.max())}")
        return host.to(self.device)

    def mask(self, env_ids: Any) -> torch.Tensor | None:
        """``env_ids`` as a (N,) bool mask on the device when it is one (``sim/interface.py is_mask``; a host
        mask is uploaded), else None (row ids: :meth:`ids`)."""
        if isinstance(env_ids, torch.Tensor) and env_ids.dtype == torch.bool and env_ids.shape == (self.num_envs,):
            return env_ids.to(self.device)
        return None

    def flag(self, name: str) -> torch.Tensor:
        """The device-side flag of input ``name`` (set when a value arrived invalid)."""
        if name not in self.bad_inputs:
            self.bad_inputs[name] = torch.zeros((), dtype=torch.bool, device=self.device)
        return self.bad_inputs[name]

    def shaped(self, name: str, value: Any, n: int, shape: tuple[int, ...]) -> torch.Tensor:
        """``value`` as a float64 tensor on the device of shape (n, *shape) (no host read of its values)."""
        value = torch.as_tensor(value).to(self.device, torch.float64)
        if value.shape != (n, *shape):
            raise ValueError(f"{name} must have shape {(n, *shape)}, got {tuple(value.shape)}")
        return value

    def rows(self, name: str, value: Any, n: int, shape: tuple[int, ...], mask: torch.Tensor | None = None
             ) -> torch.Tensor:
        """``value`` as a float64 tensor on the device of shape (n, *shape) with finite entries: checked on the host
        when it comes from there, on the device (flagged, no host read) when it is already on the device. With
        ``mask`` (n,) bool, only the masked rows must be finite (the others are not used)."""
        if isinstance(value, torch.Tensor) and value.device == self.device:
            value = self.shaped(name, value, n, shape)
            bad = ~torch.isfinite(value).flatten(1).all(dim=1)
            self.flag(name).logical_or_((bad if mask is None else bad & mask).any())
            return value
        host = torch.as_tensor(value).cpu().to(torch.float64)  # host data: checked before it is uploaded
        if host.shape != (n, *shape):
            raise ValueError(f"{name} must have shape {(n, *shape)}, got {tuple(host.shape)}")
        finite = torch.isfinite(host).reshape(n, -1).all(dim=1)
        if mask is not None:
            finite |= ~mask.cpu()
        if not bool(finite.all()):
            rows = torch.nonzero(~finite).flatten().tolist()
            raise ValueError(f"{name} has non-finite values in rows {rows[:10]}")
        return host.to(self.device)

    def flags(self) -> tuple[tuple[str, ...], torch.Tensor]:
        """The names of every flag and the flags as one bool tensor on the device (no host read)."""
        keys = (*REFERENCES, *self.bad_inputs)
        if not self.bad_inputs:
            return keys, self.bad_refs
        return keys, torch.cat([self.bad_refs, torch.stack(list(self.bad_inputs.values()))])

    def clear(self) -> None:
        """Lower every flag."""
        self.bad_refs.zero_()
        for flag in self.bad_inputs.values():
            flag.zero_()

    def raise_flagged(self, when: str) -> None:
        """Raise if a flag is up (one host read), naming each input, and lower them all.

        Raises:
            ValueError: e.g. "invalid inputs within the last 24 step calls: non-finite F_w".
        """
        keys, flags = self.flags()
        if not bool(flags.any()):
            return
        names = [k for k, bad in zip(keys, flags.tolist()) if bad]
        self.clear()
        what = [f"{k} out of [0, {self.num_envs})" if k == "env_ids" else f"non-finite {k}" for k in names]
        raise ValueError(f"invalid inputs {when}: {', '.join(what)} (robots with non-finite references diverged and "
                         "were frozen; out-of-range ids were clamped)")
