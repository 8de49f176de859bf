"""The fused CPU solve: the elementwise torch code around the ``cpp`` kernel moved into C++ calls.

:meth:`SamplingMPC.solve <dls_quadruped.mpc.sampler.SamplingMPC.solve>` on the torch path with the ``cpp``
kernel on the CPU spends a large share of its time around the kernel: cleaning the inputs, the argmin,
re-drawing and decoding the winner are ~150 small torch ops (docs/benchmarks.md "MPC solve path" times the
two paths side by side). The fused path keeps every number bit for bit (tests/mpc/test_solve_glue.py compares
every field of the result with the torch path, ``SamplingMPC.fused = False``) and does:

* input cleaning (non-finite entry -> 0, per-robot flags): ``clean_inputs`` in C++;
* the kernel and the argmin in one C++ call (``mpc_solve`` in rollout_kernel.cpp) into preallocated
  buffers (:class:`Workspace`, one per (B, G)); the controller's arbitration between warm-start groups
  (:mod:`arbitration`) then re-selects the winner from the same (B, M) costs with the torch path's call;
* the winner: its noise counters, clip, contacts, forces, limits, frames and input-cost terms in C++
  (``solve_glue.cpp``, built with ``-ffp-contract=off`` and torch's evaluation order); the log, cos, sin,
  the spline matmul and the sums stay torch calls on tensors of the torch path's shapes, because their
  results depend on torch's vector/scalar code paths and summation order.

:class:`FusedSolve` is the component ``SamplingMPC`` owns (``SamplingMPC.fused_solve``): the libraries and the
workspaces, and the steps above as methods that take what they need as arguments (the controller keeps its seed
generator, arbitration and previous solution). The library is a plain shared object built at first use like the
kernel (:mod:`cpp_kernel`, same cache directory); :func:`load` returns None (one ``RuntimeWarning``) if it cannot
be built and the solve takes the torch path.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import torch

from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.mpc import cpp_kernel
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import STATE_TERMS, Refs
from dls_quadruped.mpc.encodings import (
    F_SCALARS,
    P_SCALARS,
    SPLINE_PARAMS,
    block_slices,
    encoded_dim,
    spline_basis,
)
from dls_quadruped.mpc.kernel import KernelInputs
from dls_quadruped.mpc.solution import MPCResult, check_tensor

SOURCE = Path(__file__).with_name("solve_glue.cpp")
FLAGS = ["-O2", "-ffp-contract=off", "-fno-math-errno", "-std=gnu++17", "-shared", "-fPIC"]
"""No -march=native and no FMA contraction: the results must round like torch's separate ops."""

_P = ctypes.c_void_p
_SIGNATURES = {  # name: (restype, argtypes); pointers go as raw addresses (ints)
    "clean_inputs": (None, [ctypes.c_int] + [_P] * 11),
    "winner_noise_args": (None, [ctypes.c_int] * 3 + [ctypes.c_int64] + [_P] * 11),
    "winner_sample": (None, [ctypes.c_int] * 3 + [_P] * 11),
    "winner_forces": (None, [ctypes.c_int] * 2 + [_P] * 2 + [ctypes.c_int, _P] + [ctypes.c_int64] * 3 + [_P] * 5),
    "winner_decode": (ctypes.c_int, [ctypes.c_int] * 3 + [_P] + [ctypes.c_int64] * 3 + [_P] * 19),
    "all_finite": (ctypes.c_int, [ctypes.c_int64, _P]),
    "rotation_from_cos_sin": (None, [ctypes.c_int] + [_P] * 3),
}


@functools.lru_cache(maxsize=1)
def load() -> ctypes.CDLL | None:
    """The compiled glue library (built on first use, cached on disk by source, flags and compiler), or None
    with a RuntimeWarning if it cannot be built."""
    try:
        text = SOURCE.read_bytes()
        cxx = cpp_kernel.compiler()
        if cxx is None:
            raise RuntimeError("no C++ compiler (g++/c++) on PATH")
        key = repr((FLAGS, cxx, platform.machine()))
        digest = hashlib.sha256(cpp_kernel.source_bytes(SOURCE) + key.encode()).hexdigest()[:16]
        out = cpp_kernel.build_dir()
        out.mkdir(parents=True, exist_ok=True)
        lib_path = out / f"solve_glue_{digest}.so"
        if not lib_path.exists():
            src = out / f"solve_glue_{digest}.cpp"
            src.write_bytes(text)
            with tempfile.NamedTemporaryFile(dir=out, suffix=".so", delete=False) as tmp:
                tmp_path = Path(tmp.name)
            proc = subprocess.run([cxx, *FLAGS, f"-I{SOURCE.parent}", str(src), "-o", str(tmp_path)],
                                  capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                tmp_path.unlink(missing_ok=True)
                raise RuntimeError(proc.stderr.strip()[-2000:])
            os.replace(tmp_path, lib_path)  # atomic: concurrent builders never load a half-written file
        lib = ctypes.CDLL(str(lib_path))
        for name, (restype, argtypes) in _SIGNATURES.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = restype, argtypes
        return lib
    except Exception as err:  # noqa: BLE001 - no compiler / broken toolchain: the torch path stays correct
        warnings.warn(f"building the MPC solve glue failed ({type(err).__name__}: {err}); the solve runs its "
                      f"torch path around the kernel", RuntimeWarning, stacklevel=2)
        return None


@constant_cache
def decode_constants(cfg: SamplerConfig) -> tuple[torch.Tensor, ...]:
    """float32 constants of ``winner_decode`` and the initial cost: c (10,), nominal (4, 2), R diag (24,),
    Q diag (24,); each python float rounded to float32 as torch rounds a scalar operand."""
    act, w = cfg.action, cfg.weights
    fz_lo, fz_hi = (frac * act.weight for frac in act.force_z_range_frac)
    c = [cfg.dt, act.weight, *act.foothold_x_range, *act.foothold_y_range, fz_lo, fz_hi, act.mu, act.foot_radius]
    f32 = functools.partial(torch.tensor, dtype=torch.float32)
    return f32(c), f32(act.nominal_foothold_b), f32(w.r_diag()), f32(w.q_diag())


INPUT_WIDTHS = {"state": 24, "phase": 4, "base_xy_w": 2, "base_yaw": 1, "terrain_z_w": 4, "refs.com_height_w": 1,
                "refs.lin_vel_w": 2, "refs.yaw_rate": 1, "refs.foothold_w": 12}
"""Per-robot inputs cleaned by ``clean_inputs`` (floats per robot), in the order of the solve's fallback report."""


class Workspace:
    """Buffers and constants of the solves of one (B robots, G warm starts) for one SamplingMPC, reused solve after
    solve. Nothing here leaves a solve: the result's tensors are allocated per solve (callers keep them). One solve
    at a time per SamplingMPC (two threads solving on the same instance would share these buffers)."""

    def __init__(self, cfg: SamplerConfig, model, b: int, g: int) -> None:
        self.cfg, self.model, self.b, self.g = cfg, model, b, g
        m, n, dim = cfg.num_samples, cfg.horizon, encoded_dim(cfg.encoding)
        self.m, self.n, self.dim = m, n, dim
        self.costs = torch.empty(b, m)
        flat = torch.empty(b * sum(INPUT_WIDTHS.values()))
        self.clean, start = {}, 0
        for name, width in INPUT_WIDTHS.items():  # clean_inputs writes them one after the other
            self.clean[name] = flat[start:start + b * width].view(b, width)
            start += b * width
        self.clean_ptr = flat.data_ptr()
        self.bad = torch.zeros(len(INPUT_WIDTHS), b, dtype=torch.bool)
        self.noise = torch.empty(6, b, 1, dim // 2)  # u1, angle, log u1, radius, cos, sin: (B, 1, D/2) as rng.normals
        self.noise_views = tuple(self.noise)
        self.enc = cfg.encoding
        self.keep: dict[str, torch.Tensor] = {}
        self.init_terms = torch.empty(b, 24)
        self.input_terms = torch.empty(b, 1, n, 24)
        self.forces = torch.empty(b, 1, n, 4, 3)
        self.sumsq = torch.empty(b, 1, n, 4)
        self.norm_xy = torch.empty(b, 1, n, 4)
        self.kernel_consts = cpp_kernel.constants(cfg, model)  # prm, sigma, lo, hi, decode idx, decode weights
        self.glue_consts = decode_constants(cfg)  # c, nominal, R diag, Q diag
        self.basis_t = spline_basis(n, torch.float32).T  # encodings._decode_block's, computed once
        self.slices = block_slices(cfg.encoding)
        self.com_offset_b = torch.tensor(model.com_offset_b, dtype=torch.float32)


def all_finite(t: torch.Tensor) -> bool:
    """``bool(torch.isfinite(t).all())``, in C++ for a contiguous float32 CPU tensor once the glue is built."""
    built = getattr(load, "cache_info", None)  # never the first build from here (the fused solve builds it)
    lib = load() if built is None or built().currsize else None
    if lib is None or t.dtype is not torch.float32 or t.device.type != "cpu" or not t.is_contiguous():
        return bool(torch.isfinite(t).all())
    return bool(lib.all_finite(t.numel(), t.data_ptr()))


def _f32(t: torch.Tensor) -> torch.Tensor:
    """``t`` as a contiguous float32 CPU tensor (no copy when it already is one)."""
    if t.dtype is torch.float32 and t.device.type == "cpu" and t.is_contiguous():
        return t
    return t.detach().to("cpu", torch.float32).contiguous()


def _decoded_block(best: torch.Tensor, w: Workspace, block: str, scalars: int) -> tuple[int, int, int, int]:
    """Where the C++ glue reads the decoded ``block`` ("p" or "F") of the winners ``best`` (B, D): (address, robot
    stride, step stride, scalar stride), in floats. encodings._decode_block without copies: "first" and "discrete"
    are the encoded entries themselves; a spline is torch's matmul of the parameters with the basis, on the
    (B, 1, n, 4) view the torch path multiplies (its result (B, 1, n, N) is read transposed)."""
    kind, sl, n = getattr(w.enc, block), w.slices[block], w.n
    if kind == "first":
        return best.data_ptr() + 4 * sl.start, w.dim, 0, 1
    if kind == "discrete":
        return best.data_ptr() + 4 * sl.start, w.dim, scalars, 1
    theta = best.view(w.b, 1, w.dim)[..., sl].unflatten(-1, (scalars, SPLINE_PARAMS))
    values = (theta @ w.basis_t).contiguous()  # (B, 1, n, N): value of scalar s at step k at s N + k
    w.keep[block] = values  # alive until the C++ call has read it
    return values.data_ptr(), scalars * n, 1, n


@dataclass
class FusedCosts:
    """One fused solve up to its argmin: what :meth:`FusedSolve.winner_noise` and :meth:`FusedSolve.decode_winner`
    continue from.

    Attributes:
        inp: the kernel's inputs, cleaned (their tensors are the workspace's until the next solve).
        costs: (B, M) sample costs (the workspace's buffer); best_cost (B,), best_index (B,) long: the plain argmin.
        seconds: wall time [s] of the kernel + argmin call.
        workspace: the buffers of this (B, G).
    """

    inp: KernelInputs
    costs: torch.Tensor
    best_cost: torch.Tensor
    best_index: torch.Tensor
    seconds: float
    workspace: Workspace


class FusedSolve:
    """The fused CPU solve (module doc) of one :class:`SamplingMPC`: the two C++ libraries and one
    :class:`Workspace` per (B robots, G warm starts), reused solve after solve.

    The controller keeps what lasts between solves (its seed generator, the arbitration, the previous solution) and
    calls, per solve: :meth:`costs` (cleaning, kernel, argmin), its own arbitration on those costs,
    :meth:`winner_noise` (the winners' initial costs), then :meth:`decode_winner` or its own torch decoding, and
    :meth:`bad_inputs` for its last guard when a robot was flagged. :meth:`ready` first, every solve.

    Attributes:
        workspaces: the buffers, by (B, G).
    """

    def __init__(self) -> None:
        self.workspaces: dict[tuple[int, int], Workspace] = {}
        self.kernel_lib: ctypes.CDLL | None = None
        self.lib: ctypes.CDLL | None = None

    def ready(self) -> bool:
        """Whether both libraries are built (built here on first use; False: either cannot be, the torch path
        runs)."""
        self.kernel_lib = cpp_kernel.load()
        self.lib = load() if self.kernel_lib is not None else None
        return self.lib is not None

    def workspace(self, cfg: SamplerConfig, model, b: int, g: int) -> Workspace:
        """The buffers of B robots and G warm starts for ``cfg`` and ``model`` (new when either changed)."""
        w = self.workspaces.get((b, g))
        if w is None or w.cfg is not cfg or w.model is not model:
            w = self.workspaces[(b, g)] = Workspace(cfg, model, b, g)
        return w

    def costs(self, cfg: SamplerConfig, model, ws: torch.Tensor, group: torch.Tensor, perturb: torch.Tensor,
              seed_t: torch.Tensor, state, refs, phase: torch.Tensor, base_xy_w: torch.Tensor | None,
              base_yaw: torch.Tensor | None, terrain_z_w: torch.Tensor | None) -> FusedCosts:
        """Clean the inputs, cost every sample and take the argmin, for ``SamplingMPC.solve``'s validated arguments.

        Args:
            cfg, model: the controller's configuration and SRBD model.
            ws: (B, G, D) validated warm starts; group, perturb: (M,) the sample layout of their proportions.
            seed_t: () int64 this solve's noise seed.
            state, refs, phase, base_xy_w, base_yaw, terrain_z_w: the solve's (``SamplingMPC.solve``).
        """
        b, g = state.batch_size, ws.shape[1]
        lib, w = self.lib, self.workspace(cfg, model, b, g)
        m, n, dim, c = w.m, w.n, w.dim, w.clean
        # ---- inputs: non-finite entries -> 0 and per-robot flags (the state: the whole row); the frame's defaults
        x = _f32(state.as_vector())
        if base_yaw is None or base_xy_w is None:
            lib.clean_inputs(b, x.data_ptr(), *[x.data_ptr()] * 8, w.clean_ptr, w.bad.data_ptr())  # the safe state
            safe = c["state"]
            if base_yaw is None:
                base_yaw = safe[:, 8]
            if base_xy_w is None:  # com - R c_b: srbd.rotation_from_euler's cos, sin and the matmul stay torch's
                euler = safe[:, 6:9]
                cos_e, sin_e, rot = torch.cos(euler), torch.sin(euler), torch.empty(b, 3, 3)
                lib.rotation_from_cos_sin(b, cos_e.data_ptr(), sin_e.data_ptr(), rot.data_ptr())
                base_xy_w = (safe[:, 0:3] - rot @ w.com_offset_b)[:, :2]
        if terrain_z_w is None:
            terrain_z_w = torch.zeros(b, 4)
        for name, value, shape in (("base_xy_w", base_xy_w, (b, 2)), ("base_yaw", base_yaw, (b,)),
                                   ("terrain_z_w", terrain_z_w, (b, 4))):
            check_tensor(name, value, shape)
        inputs = [_f32(t) for t in (phase, base_xy_w, base_yaw, terrain_z_w, refs.com_height_w, refs.lin_vel_w,
                                    refs.yaw_rate, refs.foothold_w)]
        lib.clean_inputs(b, x.data_ptr(), *(t.data_ptr() for t in inputs), w.clean_ptr, w.bad.data_ptr())
        yaw, h_ref, wz_ref = c["base_yaw"].view(b), c["refs.com_height_w"].view(b), c["refs.yaw_rate"].view(b)
        foothold = c["refs.foothold_w"].view(b, 4, 3)
        # ---- the kernel and the argmin, one call
        prm, sigma, lo, hi, idx, wts = w.kernel_consts
        best_cost, best_index = torch.empty(b), torch.empty(b, dtype=torch.int64)
        args = [t.data_ptr() for t in (prm, sigma, lo, hi, idx, wts, ws, group, perturb, c["state"], c["phase"],
                                       c["base_xy_w"], yaw, c["terrain_z_w"], h_ref, c["refs.lin_vel_w"], wz_ref,
                                       foothold, w.costs, best_cost, best_index)]
        tic = time.perf_counter()
        rc = self.kernel_lib.mpc_solve(b, m, n, g, dim, int(seed_t), torch.get_num_threads(), *args)
        seconds = time.perf_counter() - tic
        if rc != 0:
            raise ValueError(f"C++ MPC kernel rejected the encoded dimension D = {dim} (must be even and <= 512)")
        inp = KernelInputs(seed_t, ws, group, perturb, c["state"], c["phase"], c["base_xy_w"], yaw, c["terrain_z_w"],
                           Refs(h_ref, c["refs.lin_vel_w"], wz_ref, foothold))
        return FusedCosts(inp, w.costs, best_cost, best_index, seconds, w)

    def winner_noise(self, run: FusedCosts, best_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The winners' noise arguments (kept in the workspace for :meth:`decode_winner`) and their initial cost.

        Args:
            run: this solve's :meth:`costs`; best_index: (B,) long the winners (after any arbitration).

        Returns:
            (B,) initial cost (``cost.initial_cost`` in torch's summation order, NaN not yet +inf), (B,) long the
            winners' warm-start groups.
        """
        w, inp = run.workspace, run.inp
        b, m, dim = w.b, w.m, w.dim
        ws_index = torch.empty(b, dtype=torch.int64)
        self.lib.winner_noise_args(b, m, dim, int(inp.seed), *(t.data_ptr() for t in (
            best_index, inp.group, ws_index, *w.noise_views[:2], inp.x0, inp.refs.com_height_w, inp.refs.lin_vel_w,
            inp.refs.yaw_rate, w.glue_consts[3], w.init_terms)))
        return w.init_terms.sum(-1), ws_index

    def decode_winner(self, run: FusedCosts, best_index: torch.Tensor, best_cost: torch.Tensor,
                      init_cost: torch.Tensor, ws_index: torch.Tensor) -> tuple[MPCResult, int]:
        """The winners re-drawn and decoded as ``SamplingMPC.decode_winners`` does (step costs NaN), after
        :meth:`winner_noise`: (MPCResult, number of robots the last guard has to look at)."""
        w, inp = run.workspace, run.inp
        u1, angle, log_u1, radius, cos_a, sin_a = w.noise_views
        torch.log(u1, out=log_u1)
        torch.sqrt(torch.mul(log_u1, -2.0, out=radius), out=radius)  # rng.normal_pair's sqrt(-2 log u1)
        torch.cos(angle, out=cos_a)
        torch.sin(angle, out=sin_a)
        best = torch.empty(w.b, w.dim)
        sigma, lo, hi = w.kernel_consts[1:4]
        self.lib.winner_sample(w.b, w.g, w.dim, *(t.data_ptr() for t in (
            inp.warm_starts, inp.group, inp.perturb, best_index, sigma, lo, hi, radius, cos_a, sin_a, best)))
        return _decode_winner(self.lib, w, best, inp, best_index, best_cost, init_cost, ws_index)

    @staticmethod
    def bad_inputs(run: FusedCosts) -> dict[str, torch.Tensor]:
        """(B,) bool per input of :data:`INPUT_WIDTHS`: the robots whose input had a non-finite entry."""
        return {name: run.workspace.bad[i].clone() for i, name in enumerate(INPUT_WIDTHS)}


def _decode_winner(lib: ctypes.CDLL, w: Workspace, best: torch.Tensor, inp, best_index: torch.Tensor,
                   best_cost: torch.Tensor, init_cost: torch.Tensor, ws_index: torch.Tensor):
    """(MPCResult of the winners ``best`` (B, D) as ``SamplingMPC.decode_winners`` computes it (step costs NaN),
    number of robots the last guard flags)."""
    b, n = w.b, w.n
    p_h = _decoded_block(best, w, "p", P_SCALARS)
    offset_h = _decoded_block(best, w, "F", F_SCALARS)
    cos_yaw, sin_yaw = torch.cos(inp.base_yaw), torch.sin(inp.base_yaw)
    const, nominal, r_diag, _ = w.glue_consts
    contact = torch.empty(b, n, 4, dtype=torch.bool)
    p_h0, F_h0, target0, force0 = torch.empty(b, 4, 2), torch.empty(b, 4, 3), torch.empty(b, 4, 3), torch.empty(b, 4, 3)
    step_costs = torch.empty(b, n)
    f_ptr = best.data_ptr()
    lib.winner_forces(b, n, f_ptr, f_ptr + 4 * best.element_size(), w.dim, *offset_h, inp.phase.data_ptr(),
                      const.data_ptr(), contact.data_ptr(), w.forces.data_ptr(), w.sumsq.data_ptr())
    torch.sqrt(w.sumsq, out=w.norm_xy)  # samples.clip_horizon's |F_xy|, torch's sqrt
    num_bad = lib.winner_decode(b, n, w.dim, *p_h, *(t.data_ptr() for t in (
        w.forces, w.norm_xy, inp.base_xy_w, cos_yaw, sin_yaw, inp.terrain_z_w, inp.refs.foothold_w, nominal,
        r_diag, const, p_h0, F_h0, target0, force0, w.input_terms, step_costs, best, w.bad, init_cost)))
    step_input = w.input_terms.sum(-1)[:, 0]  # (B, N), torch's summation order
    result = MPCResult(
        f=best[:, 0:4], d=best[:, 4:8], contact=contact[:, 0], foot_target_w=target0, force_w=force0,
        p_h=p_h0, F_h=F_h0, best_cost=best_cost, best_input_cost=step_input.sum(-1), initial_cost=init_cost,
        best_index=best_index, warm_start_index=ws_index, best_encoded=best, contact_horizon=contact,
        step_costs=step_costs, step_input_costs=step_input, fallback=torch.zeros(b, dtype=torch.bool),
        state_terms=torch.full((b, len(STATE_TERMS)), float("nan")),
    )
    return result, num_bad
