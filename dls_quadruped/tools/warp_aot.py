"""Warp's CUDA kernels compiled ahead of time, on a machine without a GPU: ``make gpu-aot``
(= ``python -m dls_quadruped.tools.warp_aot``).

A GPU node's first env build compiles MuJoCo Warp's kernels for its GPU before it steps (docs/gpu.md "Cold start":
on an H100 74 s for the flat backend and 228 s more for rough's collision kernels), out of a lease of minutes.
Warp's wheel carries NVRTC, which compiles CUDA code without a GPU or a driver, so this tool does that work on any
machine with the ``[gpu]`` extra:

1. it steps each task's env (``--tasks``) on ``warp-cpu`` with resets and pushes, so that every kernel the backend
   generates for the task's model is defined, and records the ``block_dim`` each ``wp.launch`` /
   ``wp.launch_tiled`` asks for (what a CUDA launch uses; the CPU runs every launch with a block of one); it also
   defines the ``warp`` MPC kernel's rollout and decode kernels for every size bucket;
2. it compiles every Warp module then defined for ``sm_<arch>``, at the module's default ``block_dim`` (what Warp
   loads before a graph capture) and at each recorded one, into Warp's kernel cache at ``--cache`` (the layout of
   ``WARP_CACHE_PATH``: ``<cache>/<warp version>/wp_<module>_<hash>/wp_<module>_<hash>.sm<arch>.cubin``), with
   Warp's own compiler and names: the files Warp's load on a GPU of that architecture looks up;
3. it writes ``warp_aot.json`` beside the cache: each module variant, its file, size and compile time.

``make gpu-caches`` then packs the folder for the node (``tools/gpu_lease.sh`` unpacks it before the first build).

What it cannot cover: a kernel whose code MuJoCo Warp picks by device type (a few thread counts and grid sizes) is
compiled here in its CPU form, which a GPU does not load; the node compiles those itself. ``--format`` must match
the node's choice: Warp compiles ``cubin`` when the node's driver is older than Warp's CUDA toolkit (the nodes seen so
far: driver 13.0, toolkit of warp-lang 1.19.0 newer), ``ptx`` otherwise. Whether a node loads these files is
measured on the node, from Warp's load lines ("(cached)" or "(compiled)"); not yet measured.

Uses Warp 1.19's internals (``Module.resolve_options`` and ``Module._compile``, the calls ``Module.load`` makes;
``init_kernel_cache``, as Warp's own tests do); another Warp version is refused with a message.
"""

from __future__ import annotations

import contextlib
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from dls_quadruped.cli import ArgumentParser, UserError, positive_int, run_cli
from dls_quadruped.core.json_io import write_json

WARP_VERSION = "1.19.0"
"""The Warp whose module internals this tool calls (the ``[gpu]`` extra's pin)."""

CUDA_DEFAULT_BLOCK_DIM = 256
"""What a CUDA launch uses when it asks for no ``block_dim`` (or a non-positive one)."""

TASKS = ("base", "rough")


def _warp():
    import warp as wp

    if wp.__version__ != WARP_VERSION:
        raise UserError(f"needs warp-lang=={WARP_VERSION} (the [gpu] extra's pin), found {wp.__version__}")
    return wp


@contextlib.contextmanager
def record_launches(wp, variants: dict):
    """Record into ``variants`` (``(module name, block_dim) -> Module``) the module and CUDA ``block_dim`` of every
    ``wp.launch`` / ``wp.launch_tiled`` made inside; the launches run as usual."""
    originals = {name: getattr(wp, name) for name in ("launch", "launch_tiled")}

    def recorded(fn):
        def wrapper(kernel, *args, **kwargs):
            block_dim = kwargs.get("block_dim")
            if block_dim is None or block_dim <= 0:
                block_dim = CUDA_DEFAULT_BLOCK_DIM
            variants.setdefault((kernel.module.name, int(block_dim)), kernel.module)
            return fn(kernel, *args, **kwargs)
        return wrapper

    for name, fn in originals.items():
        setattr(wp, name, recorded(fn))
    try:
        yield variants
    finally:
        for name, fn in originals.items():
            setattr(wp, name, fn)


def define_task_kernels(wp, tasks, num_envs: int, steps: int, variants: dict) -> dict:
    """Step each task's env on ``warp-cpu`` (random actions large enough to topple robots, pushes every few steps)
    while :func:`record_launches` runs; returns ``{task: resets seen}``."""
    import torch

    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    seen = {}
    push = {"func": "push_robot", "mode": "interval", "interval_s": [0.04, 0.08],
            "params": {"velocity_range": [-0.5, 0.5]}}
    with record_launches(wp, variants):
        for task in tasks:
            overrides = {"scene": {"backend": "warp-cpu", "num_workers": 0}, "env": {"episode_length_s": 0.1},
                         "events": {"push": push}}
            env = LocomotionEnv(load_task(task, overrides=overrides), num_envs=num_envs, seed=0, verbose=False)
            try:
                g = torch.Generator().manual_seed(0)
                resets = 0
                for _ in range(steps):
                    _, _, dones, _ = env.step(torch.randn(num_envs, env.num_actions, generator=g) * 3)
                    resets += int(dones.sum())
                seen[task] = resets
            finally:
                env.close()
    return seen


def define_mpc_kernels() -> int:
    """Define the ``warp`` MPC kernel's rollout and decode kernels for every size bucket; returns the bucket count."""
    from dls_quadruped.mpc import warp_argmin, warp_decode, warp_kernel  # noqa: F401  (their module kernels)

    for size in warp_kernel.BUCKETS:
        warp_kernel.rollout_kernel(size)
        warp_decode.decode_kernel(size)
    return len(warp_kernel.BUCKETS)


def module_variants(wp, recorded: dict) -> dict:
    """Every defined Warp module at its default ``block_dim``, plus the recorded ``(module, block_dim)`` pairs."""
    from warp._src.context import user_modules

    variants = {(m.name, int(m.options["block_dim"])): m for m in list(user_modules.values())
                if m.kernels}
    variants.update(recorded)
    return variants


def artifact(wp, module, block_dim: int, arch: int, fmt: str) -> Path:
    """The file Warp's load of ``module`` at ``block_dim`` on an ``sm_<arch>`` GPU looks up in its kernel cache."""
    name = module._get_compile_output_name(None, arch, "", fmt == "ptx", block_dim=block_dim)
    return Path(wp.config.kernel_cache_dir) / module.get_module_identifier(block_dim) / name


def compile_variant(wp, module, block_dim: int, arch: int, fmt: str) -> dict:
    """Compile one module variant into the kernel cache (skipped by Warp if there already); returns its row."""
    t0 = time.perf_counter()
    row = {"module": module.name, "block_dim": block_dim}
    try:
        options = module.resolve_options(wp.config, block_dim=block_dim)
        row["compiled"] = bool(module._compile(None, None, output_arch=arch, use_ptx=fmt == "ptx", options=options))
        path = artifact(wp, module, block_dim, arch, fmt)
        row.update(file=str(path.relative_to(wp.config.kernel_cache_dir)), bytes=path.stat().st_size)
    except Exception as e:  # noqa: BLE001 - one module's failure is reported and the others still compile
        row["error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:300]
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog="dls_quadruped.tools.warp_aot", description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", required=True, type=Path,
                   help="Warp's kernel cache folder (what WARP_CACHE_PATH names on the node, e.g. GPU_CACHES/warp)")
    p.add_argument("--arch", type=positive_int, default=90, help="the node's GPU architecture (90: H100, H200)")
    p.add_argument("--format", choices=("cubin", "ptx"), default="cubin",
                   help="cubin when the node's driver is older than Warp's CUDA toolkit (the nodes seen so far)")
    p.add_argument("--tasks", default=",".join(TASKS), help=f"tasks whose kernels to define (default {TASKS})")
    p.add_argument("--num-envs", type=positive_int, default=2, help="robots of each dry run on warp-cpu")
    p.add_argument("--steps", type=positive_int, default=12, help="env steps of each dry run")
    p.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1, help="modules compiled at once")
    return p


def main(argv=None) -> dict:
    args = build_parser().parse_args(argv)
    from dls_quadruped.envs.config import available_tasks

    tasks = [t for t in args.tasks.split(",") if t]
    unknown = [t for t in tasks if t not in available_tasks()]
    if not tasks or unknown:
        raise UserError(f"--tasks {args.tasks!r} names no task or unknown ones {unknown} "
                         f"(allowed: {', '.join(available_tasks())})")
    wp = _warp()
    wp.config.quiet = True
    wp.init()
    from warp._src.build import init_kernel_cache
    from warp._src.context import runtime

    if args.arch not in (runtime.nvrtc_supported_archs or ()):
        raise UserError(f"this Warp's NVRTC cannot compile for sm_{args.arch} "
                        f"(it can: {sorted(runtime.nvrtc_supported_archs or ())})")
    t0 = time.perf_counter()
    recorded: dict = {}
    resets = define_task_kernels(wp, tasks, args.num_envs, args.steps, recorded)  # CPU kernels: the usual cache
    buckets = define_mpc_kernels()
    variants = module_variants(wp, recorded)
    defined_s = time.perf_counter() - t0
    init_kernel_cache(str(args.cache))  # <cache>/<warp version>, as WARP_CACHE_PATH=<cache> on the node
    print(f"warp_aot: {len(variants)} module variants defined in {defined_s:.0f} s (tasks {tasks}, "
          f"resets {resets}, {buckets} MPC buckets); compiling for sm_{args.arch} ({args.format}), "
          f"{args.jobs} at once", flush=True)
    t1 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(lambda kv: compile_variant(wp, kv[1], kv[0][1], args.arch, args.format),
                             sorted(variants.items(), key=lambda kv: kv[0])))
    failed = [r for r in rows if "error" in r]
    report = {"warp": wp.__version__, "arch": args.arch, "format": args.format, "tasks": tasks, "resets": resets,
              "variants": len(rows), "compiled": sum(bool(r.get("compiled")) for r in rows),
              "failed": len(failed), "define_s": round(defined_s, 1),
              "compile_s": round(time.perf_counter() - t1, 1),
              "bytes": sum(r.get("bytes", 0) for r in rows), "rows": rows}
    write_json(report, args.cache / "warp_aot.json")
    print(f"warp_aot: {report['variants'] - len(failed)} of {len(rows)} variants in {args.cache} "
          f"({report['bytes'] / 1e6:.1f} MB, compile {report['compile_s']:.0f} s)")
    for r in failed:
        print(f"  failed: {r['module']} block_dim {r['block_dim']}: {r['error']}")
    return report


if __name__ == "__main__":
    run_cli(main)
