"""The ``cpp`` kernel: the whole per-sample pipeline in hand-written C++ (rollout_kernel.cpp), CPU only.

Same inputs and semantics as :func:`dls_quadruped.mpc.kernel.reference_costs` (counter-hash noise,
box clip, decode, forces from gravity-compensation offsets, Table 1 limits, frames, contacts, explicit-Euler SRBD,
quadratic cost, NaN -> +inf), computed per sample in registers: one OpenMP loop over blocks of 16 samples, the N steps
inside, only the (B, M) costs are written. float32 like the torch kernels.

Build: the source is compiled at first use with the system C++ compiler into a plain shared library
(``g++ -O3 -march=native -fopenmp``; if that fails, generic ``-O3 -fopenmp``, then without OpenMP, and a
build that fell back says once per process which flags it used), cached by source hash, flags and host CPU
in torch's extensions directory (``$TORCH_EXTENSIONS_DIR`` or ``~/.cache/torch_extensions``), and
called through ctypes with the tensors' data pointers. No torch headers are involved, so a cold
build takes about a second. :func:`load` returns None (after one ``RuntimeWarning``) if no
compiler works; the caller then falls back to the ``fast`` kernel. ``load("x86-64-v3")`` and
``load("scalar")`` build the comparison variants of the benchmark (:data:`VARIANTS`).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import torch

from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import (
    P_SCALARS,
    SPLINE_PARAMS,
    block_slices,
    encoded_dim,
    spline_basis,
)
from dls_quadruped.mpc.samples import encoded_bounds, sigma_vector
from dls_quadruped.mpc.srbd import SRBDModel

SOURCE = Path(__file__).with_name("rollout_kernel.cpp")
HEADERS = (Path(__file__).with_name("counter_hash.h"),)
"""The headers the C++ sources include (``-I`` the package's ``mpc/``; their bytes are part of the build's key)."""


def source_bytes(source: Path) -> bytes:
    """``source`` and :data:`HEADERS`, the bytes a cached build must match."""
    return source.read_bytes() + b"".join(h.read_bytes() for h in HEADERS)


FLAG_SETS = (
    ["-O3", "-march=native", "-fopenmp", "-fno-math-errno"],
    ["-O3", "-fopenmp", "-fno-math-errno"],
    ["-O3", "-fno-math-errno"],
)
"""Compiler flags of the host build, tried in order (the first set that compiles wins)."""
COMMON_FLAGS = ["-std=gnu++17", "-ffp-contract=fast", "-shared", "-fPIC"]
GCC_FLAGS = ["--param=max-completely-peel-times=8"]
"""GCC only. At -O3 GCC fully unrolls loops of up to 16 iterations before its loop vectoriser runs and
leaves the unrolled 16-lane loops to the basic-block vectoriser, which misses some of them (on NEON
the decode loop); with at most 8 peels the lane loops reach the loop vectoriser whole, which
vectorises every one of them (tests/mpc/test_cpp_vectorise.py) and unrolls the 2-4 vector
iterations afterwards."""
NO_VECTORISE = ["-fno-tree-vectorize", "-fno-tree-slp-vectorize"]
VARIANTS = ("native", "x86-64-v3", "scalar")
"""Builds :func:`load` knows: the host build (``native``, with the fallbacks of :data:`FLAG_SETS`),
AVX2 + FMA without AVX-512 (``x86-64-v3``: what a machine without AVX-512 runs), and the host build
without auto-vectorisation (``scalar``); the last two are for the benchmark's side-by-side timing."""

_F = ctypes.POINTER(ctypes.c_float)
_I32 = ctypes.POINTER(ctypes.c_int32)
_I64 = ctypes.POINTER(ctypes.c_int64)


def build_dir() -> Path:
    """Where the compiled library is cached (torch's default extensions directory)."""
    root = os.environ.get("TORCH_EXTENSIONS_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "torch_extensions")
    return Path(root) / "dls_mpc_cpp"


def flag_sets(variant: str = "native") -> tuple[list[str], ...]:
    """The flag sets tried in order for one of :data:`VARIANTS` (only the host build has fallbacks)."""
    if variant == "native":
        return tuple(FLAG_SETS)
    if variant == "x86-64-v3":
        return (["-O3", "-march=x86-64-v3", "-fopenmp", "-fno-math-errno"],)
    if variant == "scalar":
        return ([*FLAG_SETS[0], *NO_VECTORISE],)
    raise ValueError(f"unknown C++ kernel variant {variant!r}; allowed: {', '.join(VARIANTS)}")


def compiler() -> str | None:
    """The C++ compiler: ``$CXX``, else g++, else c++ on PATH (None if there is none)."""
    return os.environ.get("CXX") or shutil.which("g++") or shutil.which("c++")


@functools.lru_cache(maxsize=8)
def extra_flags(cxx: str) -> tuple[str, ...]:
    """:data:`GCC_FLAGS` if ``cxx`` is GCC (clang rejects them), else nothing."""
    try:
        out = subprocess.run([cxx, "--version"], capture_output=True, text=True, check=False, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return ()
    return tuple(GCC_FLAGS) if "Free Software Foundation" in out and "clang" not in out.lower() else ()


def _compile(src: Path, lib: Path, variant: str) -> tuple[str, list[str]]:
    """Compile ``src`` into ``lib`` with the first flag set of ``variant`` that works.

    Returns ('', flags used) on success, else (the last compiler error, [])."""
    cxx = compiler()
    if cxx is None:
        return "no C++ compiler (g++/c++) on PATH", []
    error = ""
    for flags in flag_sets(variant):
        with tempfile.NamedTemporaryFile(dir=lib.parent, suffix=".so", delete=False) as tmp:
            tmp_path = Path(tmp.name)
        cmd = [cxx, *flags, *COMMON_FLAGS, *extra_flags(cxx), f"-I{SOURCE.parent}", str(src), "-o", str(tmp_path)]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode == 0:
            lib.with_suffix(".flags").write_text(" ".join(flags))  # before the library: a reader sees both
            os.replace(tmp_path, lib)  # atomic: concurrent builders never load a half-written file
            return "", flags
        tmp_path.unlink(missing_ok=True)
        error = f"{' '.join(cmd)}: {proc.stderr.strip()[-2000:]}"
    return error, []


def _host_signature() -> str:
    """The CPU the library is built for: ``-march=native`` code must not be reused on another CPU
    (a home directory shared by heterogeneous cluster nodes would otherwise hand an AVX-512
    build to a node without it)."""
    cpu = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith(("model name", "flags")):
                    cpu += "|" + line.split(":", 1)[1].strip()
                if line.startswith("flags"):
                    break
    except OSError:
        cpu += "|" + platform.processor()
    return cpu


@functools.lru_cache(maxsize=len(VARIANTS))
def load(variant: str = "native") -> ctypes.CDLL | None:
    """The compiled kernel library (built on first use), or None with a RuntimeWarning if it cannot be built.

    ``variant`` is one of :data:`VARIANTS`. Cached per process; if the build used a fallback flag set
    (the first one failed), that is printed to stderr once per process, even when the library comes
    from the on-disk cache. The library's ``build_flags`` attribute holds the flag set it was built with."""
    try:
        text = SOURCE.read_bytes()
        cxx = compiler() or ""
        key = repr((flag_sets(variant), COMMON_FLAGS, extra_flags(cxx) if cxx else (), _host_signature()))
        digest = hashlib.sha256(source_bytes(SOURCE) + key.encode()).hexdigest()[:16]
        out = build_dir()
        out.mkdir(parents=True, exist_ok=True)
        lib_path = out / f"rollout_kernel_{digest}.so"
        flags_path = lib_path.with_suffix(".flags")  # the flag set the library was built with
        if not lib_path.exists():
            src = out / f"rollout_kernel_{digest}.cpp"
            src.write_bytes(text)
            error, _ = _compile(src, lib_path, variant)
            if error:
                raise RuntimeError(error)
        used = flags_path.read_text().strip() if flags_path.exists() else ""
        first = " ".join(flag_sets(variant)[0])
        if used and used != first:
            print(f"dls_quadruped: the C++ MPC kernel ({variant}) did not build with '{first}'; "
                  f"built with '{used}' instead (slower)", file=sys.stderr, flush=True)
        lib = ctypes.CDLL(str(lib_path))
        lib.build_flags = used or first
        fn = lib.mpc_costs
        fn.restype = ctypes.c_int
        fn.argtypes = [ctypes.c_int] * 5 + [ctypes.c_int64, ctypes.c_int] + [_F] * 4 + [_I32, _F] + [_F, _I64, _F] \
            + [_F] * 10
        solve = lib.mpc_solve  # mpc_costs + argmin; raw addresses (ints): the solve's hot path skips ctypes.cast
        solve.restype = ctypes.c_int
        solve.argtypes = [ctypes.c_int] * 5 + [ctypes.c_int64, ctypes.c_int] + [ctypes.c_void_p] * 21
        return lib
    except Exception as err:  # noqa: BLE001 - no compiler / broken toolchain: caller falls back, stays correct
        warnings.warn(f"building the C++ MPC kernel ({variant}) failed ({type(err).__name__}: {err}); "
                      f"falling back to the 'fast' kernel", RuntimeWarning, stacklevel=2)
        return None


def decode_tables(cfg: SamplerConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """(N, 20, 4) int32 indices and float32 weights: decoded scalar s at step k = sum_j w[k, s, j] P[idx[k, s, j]].

    Scalars 0..7 are p (x, y leg-major), 8..19 are F (x, y, z leg-major), as in encodings.decode_parts.
    """
    enc, n = cfg.encoding, cfg.horizon
    sl = block_slices(enc)
    basis = spline_basis(n, torch.float32).tolist()
    idx = torch.zeros(n, 20, 4, dtype=torch.int32)
    wts = torch.zeros(n, 20, 4, dtype=torch.float32)
    for block, kind, scalars, first in (("p", enc.p, P_SCALARS, 0), ("F", enc.F, 12, P_SCALARS)):
        start = sl[block].start
        for k in range(n):
            for s in range(scalars):
                if kind == "first":
                    idx[k, first + s, 0], wts[k, first + s, 0] = start + s, 1.0
                elif kind == "discrete":
                    idx[k, first + s, 0], wts[k, first + s, 0] = start + k * scalars + s, 1.0
                else:
                    for j in range(SPLINE_PARAMS):
                        idx[k, first + s, j] = start + s * SPLINE_PARAMS + j
                        wts[k, first + s, j] = basis[k][j]
    return idx, wts


@functools.lru_cache(maxsize=64)
def constants(cfg: SamplerConfig, model: SRBDModel) -> tuple[torch.Tensor, ...]:
    """Per-config constant arrays of the kernel: params, sigma, lo, hi, decode indices, decode weights."""
    act, w = cfg.action, cfg.weights
    inertia = torch.tensor(model.inertia_b, dtype=torch.float64)
    fz_lo, fz_hi = (frac * act.weight for frac in act.force_z_range_frac)
    prm = [cfg.dt, model.mass, model.gravity, *inertia.flatten().tolist(),
           *torch.linalg.inv(inertia).flatten().tolist(), act.mu, fz_lo, fz_hi, *act.foothold_x_range,
           *act.foothold_y_range, *(v for leg in act.nominal_foothold_b for v in leg[:2]), act.foot_radius,
           w.z, w.vx, w.vy, w.vz, w.roll, w.pitch, w.roll_rate, w.pitch_rate, w.yaw_rate, w.foothold_xy, act.weight]
    assert len(prm) == 48
    lo, hi = encoded_bounds(cfg)
    idx, wts = decode_tables(cfg)
    f32 = functools.partial(torch.tensor, dtype=torch.float32)
    return f32(prm), f32(sigma_vector(cfg)), f32(lo), f32(hi), idx.contiguous(), wts.contiguous()


def _ptr(t: torch.Tensor, kind: type) -> ctypes._Pointer:
    return ctypes.cast(t.data_ptr(), kind)


def cpp_costs(inp, cfg: SamplerConfig, model: SRBDModel, lib: ctypes.CDLL) -> torch.Tensor:
    """(B, M) costs of :class:`dls_quadruped.mpc.kernel.KernelInputs` ``inp`` with the C++ kernel (CPU tensors)."""
    b, m = inp.x0.shape[0], inp.group.shape[0]
    g, dim = inp.warm_starts.shape[1], encoded_dim(cfg.encoding)
    prm, sigma, lo, hi, idx, wts = constants(cfg, model)
    f32 = lambda t: t.detach().to("cpu", torch.float32).contiguous()
    arrays = [f32(inp.warm_starts), inp.group.to("cpu", torch.int64).contiguous(), f32(inp.perturb), f32(inp.x0),
              f32(inp.phase), f32(inp.base_xy_w), f32(inp.base_yaw), f32(inp.terrain_z_w),
              f32(inp.refs.com_height_w), f32(inp.refs.lin_vel_w), f32(inp.refs.yaw_rate), f32(inp.refs.foothold_w)]
    out = torch.empty(b, m, dtype=torch.float32)
    kinds = [_F, _I64] + [_F] * 10
    rc = lib.mpc_costs(b, m, cfg.horizon, g, dim, int(inp.seed), torch.get_num_threads(),
                       _ptr(prm, _F), _ptr(sigma, _F), _ptr(lo, _F), _ptr(hi, _F), _ptr(idx, _I32), _ptr(wts, _F),
                       *(_ptr(a, k) for a, k in zip(arrays, kinds, strict=True)), _ptr(out, _F))
    if rc != 0:
        raise ValueError(f"C++ MPC kernel rejected the encoded dimension D = {dim} (must be even and <= 512)")
    return out
