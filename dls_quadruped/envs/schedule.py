"""Episode schedule: every random number of the env as a pure function of (seed, episode key, episode, stream, draw).

Why: with one global torch generator, what robot i draws at its 10 s command resample (or its next
push) depends on how many numbers the *other* robots drew before, i.e. on when they fell. Two
controllers evaluated with the same seed then see different commands, pushes and terrain once any
robot falls, and a per-episode difference between them is no longer paired. Here each draw is a hash
of

    (seed, key of the env's episode, how many episodes that env has started, stream, draw count)

so env i's j-th episode is fixed before the run, whatever the other robots do, and so is every
episode of another env given the same key (``episode_keys``: e.g. K policies batched in one env
on the same E episodes use keys ``arange(K * E) % E``).

Streams are named per purpose (``"command"``, ``"push_robot"``, ``"obs_noise"``, ...): each has its
own draw counter per env, so adding observation noise to a task does not shift its commands.

The generator is the project's counter-based integer hash (``core.hashing.hash32``, the MPC
sampler's), chained over the key fields, in int64 arithmetic that never overflows, so it is exact on
any torch device; a uniform is its top 24 bits / 2**24 (every float32 in [0, 1) on that grid).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from contextlib import contextmanager

import torch

from dls_quadruped.core.compile import fused_method
from dls_quadruped.core.hashing import hash32


@torch.compiler.assume_constant_result  # a compiled caller (a reset's draws) sees the id as a constant
def stream_id(name: str) -> int:
    """Stable 32-bit id of a stream name (crc32: the same in every process and Python version)."""
    return zlib.crc32(name.encode())


def _draw_bits(seed_h: torch.Tensor, stream_h: int, keys: torch.Tensor, episode: torch.Tensor,
               count: torch.Tensor, env_ids: torch.Tensor, element_h: torch.Tensor) -> torch.Tensor:
    """(n, size) hashes of the envs ``env_ids``: h = hash(seed); then h = hash(h ^ hash(field)) over (key,
    episode + 1, stream id, draw count); then one hash per element (``EpisodeSchedule._bits``). ``seed_h`` is the
    seed's hash (a 0-dim tensor), ``stream_h`` the stream id's (a Python int: no upload; symbolic when compiled),
    ``element_h`` (size,) the hashes of the element indices."""
    # the per-env fields hashed in one stacked call: the same numbers as hashing each on its own
    key_ep_count = hash32(torch.stack([keys[env_ids], episode[env_ids] + 1, count[env_ids]]))
    h = hash32(seed_h ^ key_ep_count[0])
    h = hash32(h ^ key_ep_count[1])
    h = hash32(h ^ stream_h)
    h = hash32(h ^ key_ep_count[2])
    return hash32(h[:, None] ^ element_h[None, :])


class EpisodeSchedule:
    """Per-env episode counters and per-stream draw counters of ``num_envs`` envs.

    Args:
        seed: schedule seed (``env.seed``).
        num_envs: B.
        device: where the counters and draws live.
        episode_keys: (B,) long, the episode key of each env (default ``arange(B)``).
        compile: whether a draw's hash chain runs as one compiled kernel (``core/compile.py``); setting the
            attribute later takes effect from the next draw (the env sets it once its scene is built, after the
            terrain's first draws).

    Attributes:
        episode: (B,) long, episodes each env has started since the schedule began (-1 before the first).
    """

    _draw = fused_method("EpisodeSchedule draws", dynamic=True)(staticmethod(_draw_bits))
    """:func:`_draw_bits`, compiled when ``compile`` is True (its batch size dynamic)."""

    def __init__(self, seed: int, num_envs: int, device: torch.device | str = "cpu",
                 episode_keys: torch.Tensor | None = None, compile: bool = False):
        self.num_envs = int(num_envs)
        self._compile = bool(compile)
        self.device = torch.device(device)
        self._hashes: dict[tuple, int | torch.Tensor] = {}
        self._advance: torch.Tensor | None = None  # see only()
        self._draws: dict[str, torch.Tensor] = {}  # per stream, the draws each env made in its episode
        self.seed_hash = torch.zeros((), dtype=torch.long, device=self.device)
        """hash32 of the seed, a 0-dim tensor: compiled draws read it as an input, so another seed is not a
        recompile."""
        self.restart(seed, episode_keys)

    @property
    def compile(self) -> bool:
        return self._compile

    @compile.setter
    def compile(self, value: bool) -> None:
        self._compile = bool(value)
        EpisodeSchedule._draw.renew(self)  # the next draw makes it anew, compiled or not

    def restart(self, seed: int, episode_keys: torch.Tensor | None = None) -> None:
        """Start over: no episode started yet, keys ``episode_keys`` (B,) (default ``arange(B)``).

        Raises:
            ValueError: keys not (B,) non-negative integers.
        """
        b = self.num_envs
        if episode_keys is None:
            keys = torch.arange(b, device=self.device)
        else:
            keys = torch.as_tensor(episode_keys, device=self.device)
            if keys.shape != (b,) or keys.dtype.is_floating_point or keys.dtype == torch.bool or bool((keys < 0).any()):
                raise ValueError(f"episode_keys must be {b} non-negative integers (one per env), "
                                 f"got shape {tuple(keys.shape)} of {keys.dtype}")
        self._set_seed(seed)
        self.keys = keys.to(torch.long).clone()
        self.episode = torch.full((b,), -1, dtype=torch.long, device=self.device)
        for count in self._draws.values():  # zeroed, not dropped: a compiled caller's streams stay where they were
            count.zero_()

    def start_episodes(self, env_ids: torch.Tensor) -> None:
        """``env_ids`` (ids, or a (B,) bool mask: static shapes) begin their next episode: episode += 1, every
        stream's draw count restarts."""
        if env_ids.dtype == torch.bool:
            self.episode += env_ids.to(torch.long)
            for count in self._draws.values():
                count.masked_fill_(env_ids, 0)
            return
        self.episode[env_ids] += 1
        for count in self._draws.values():
            count.index_fill_(0, env_ids, 0)  # a scalar fill: no host-to-device copy of the 0

    @contextmanager
    def only(self, advance: torch.Tensor) -> Iterator[None]:
        """Draws made inside advance the draw counts of the rows where ``advance`` (n,) bool is True only.

        For masked updates without a host read: draw for every env (``env_ids = arange(B)``), keep the draws
        of the masked envs (``torch.where``), and their numbers are those an indexed draw of the masked envs
        alone would give, while the others' next draws are unchanged. ``advance`` is indexed like the
        ``env_ids`` of each draw inside.
        """
        if self._advance is not None:
            raise RuntimeError("EpisodeSchedule.only does not nest")
        self._advance = advance
        try:
            yield
        finally:
            self._advance = None

    def _bits(self, env_ids: torch.Tensor, shape: tuple[int, ...], stream: str) -> torch.Tensor:
        """(n, *shape) int64 hashes in [0, 2**32); advances ``stream``'s draw count of ``env_ids`` by one."""
        env_ids = torch.as_tensor(env_ids, device=self.device, dtype=torch.long)
        count = self._draws.get(stream)  # get, not setdefault: a compiled caller guards on this stream alone
        if count is None:  # a normal tensor even under inference mode (rsl-rl's rollouts): reset in place outside it
            with torch.inference_mode(False):
                count = self._draws[stream] = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        n, size = len(env_ids), 1
        for s in shape:
            size *= int(s)
        # the constant hashes (seed, stream id, element index) are cached
        bits = self._draw(self.seed_hash, self._constant_hash("stream", stream_id(stream)),
                          self.keys, self.episode, count, env_ids, self._element_hash(size))
        if self._advance is None:
            count[env_ids] += 1
        else:
            count[env_ids] += self._advance.to(torch.long)
        return bits.reshape(n, *shape)

    def _set_seed(self, seed: int) -> None:
        self.seed = int(seed)
        self.seed_hash.fill_(self._constant_hash("seed", self.seed))  # a scalar fill: no host-to-device copy

    def _constant_hash(self, kind: str, value: int) -> int:
        """hash32 of one integer (the seed, a stream id), cached."""
        key = (kind, int(value))
        if key not in self._hashes:
            # hash32's int64 arithmetic never overflows, so on a Python int it gives the tensor's value, without a
            # tensor read back to the host
            self._hashes[key] = int(hash32(int(value)))
        return self._hashes[key]

    def _element_hash(self, size: int) -> torch.Tensor:
        """hash32 of arange(size) on the schedule's device, cached."""
        key = ("element", size)
        if key not in self._hashes:
            self._hashes[key] = hash32(torch.arange(size, device=self.device, dtype=torch.long))
        return self._hashes[key]

    def uniform(self, env_ids: torch.Tensor, shape: tuple[int, ...] = (), low: float | torch.Tensor = 0.0,
                high: float | torch.Tensor = 1.0, stream: str = "default") -> torch.Tensor:
        """(n, *shape) float32 U[low, high) for the envs ``env_ids`` (n,), one draw of ``stream`` each. ``low`` and
        ``high`` are numbers or 0-dim float64 tensors on the device (read by compiled code without a host read or
        a recompile when they change; the same float32 result as the numbers)."""
        u = (self._bits(env_ids, tuple(shape), stream) >> 8).to(torch.float32) * (1.0 / 16777216.0)  # 24 bits / 2^24
        if isinstance(low, torch.Tensor) or isinstance(high, torch.Tensor):
            return low + (high - low) * u  # the span in float64, then float32 as with Python numbers
        return float(low) + (float(high) - float(low)) * u

    def integers(self, env_ids: torch.Tensor, low: int, high: int, shape: tuple[int, ...] = (),
                 stream: str = "default") -> torch.Tensor:
        """(n, *shape) long, uniform on {low, ..., high - 1}."""
        if high <= low:
            raise ValueError(f"integers: need high > low, got [{low}, {high})")
        return low + self._bits(env_ids, tuple(shape), stream) % (high - low)

    def state_dict(self) -> dict:
        """Counters and keys (for a checkpoint: a resumed run draws what the uninterrupted one would)."""
        return {"seed": self.seed, "keys": self.keys.cpu().clone(), "episode": self.episode.cpu().clone(),
                "draws": {k: v.cpu().clone() for k, v in self._draws.items()}}

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict` output.

        Raises:
            ValueError: saved for another number of envs.
        """
        if tuple(state["episode"].shape) != (self.num_envs,):
            raise ValueError(f"schedule state is for {state['episode'].numel()} envs, this env has {self.num_envs}")
        self._set_seed(state["seed"])
        self.keys = state["keys"].to(self.device, torch.long).clone()
        self.episode = state["episode"].to(self.device, torch.long).clone()
        self._draws = {k: v.to(self.device, torch.long).clone() for k, v in state["draws"].items()}
