"""Pack the ``[gpu]`` wheels for a GPU node that takes files in size-limited transfers.

``make gpu-pack`` (= ``python -m dls_quadruped.tools.gpu_pack``) is the route to a node with no network whose
jobs carry at most a few tens of MB each (docs/gpu.md "Offline install"): it downloads the wheels
``tools/wheelhouse.py`` would (the closure of ``dls_quadruped[gpu]`` for the node's Python, minus what the node
already has), unpacks them into one folder (an import path: no pip run on the node), leaves out Warp's
CPU-only compiler ``warp/bin/warp-clang.so`` (CUDA kernels do not need it) and Warp's examples, packs the folder
with ``xz`` and splits the archive into parts of at most ``--part-mb`` MB. It writes beside the parts
``unpack.sh``, the one line that joins and unpacks them on the node (``SITE`` the folder, default
``/tmp/gpu_site``), to be followed by ``export PYTHONPATH=$SITE:$PYTHONPATH``.

The working tree runs from its checkout (``PYTHONPATH=.``), so the package's own wheel is not packed.

``--caches DIR`` packs a compile-cache folder instead (``make gpu-caches``): run the node's jobs with
``WARP_CACHE_PATH=DIR/warp TORCHINDUCTOR_CACHE_DIR=DIR/inductor``, bring ``DIR`` back packed, and the next node
unpacks it (``unpack_caches.sh``, into ``$CACHES``, default ``/tmp/gpu_caches``) before its first build, so
Warp's kernels and inductor's Triton code are not compiled again (docs/gpu.md "Cold start"); Warp's CUDA sources and
MathDx link-time objects are left out (:func:`warp_cache_member`). ``make gpu-aot`` (``tools/warp_aot.py``) fills
``DIR/warp`` without a GPU.
"""

from __future__ import annotations

import lzma
import subprocess
import tarfile
import tempfile
import zipfile
from pathlib import Path

from dls_quadruped.cli import ArgumentParser, UserError, positive_float, run_cli
from dls_quadruped.tools import wheelhouse

NODE_HAS = ("torch,numpy,pyyaml,tqdm,absl-py,etils,cloudpickle,packaging,matplotlib,tensorboard,onnx,"
            "sympy,mpmath,typing-extensions,pin")
"""What the torch 2.11 + CUDA 13 GPU images seen so far already hold (pin: not needed by the Warp backends)."""

LEAVE_OUT = ("warp/bin/warp-clang.so", "warp/examples/")
"""Paths inside the wheels not unpacked: Warp's LLVM CPU compiler (69 MB) and its examples."""


def unpack(wheels: Path, site: Path, leave_out: tuple[str, ...] = LEAVE_OUT) -> list[str]:
    """Unpack every wheel in ``wheels`` (but this package's own) into ``site``; returns the wheels unpacked."""
    done = []
    for whl in sorted(wheels.glob("*.whl")):
        if whl.name.startswith("dls_quadruped-"):
            continue
        with zipfile.ZipFile(whl) as z:
            for info in z.infolist():
                if not info.filename.startswith(leave_out):
                    z.extract(info, site)
        done.append(whl.name)
    return done


def warp_cache_member(info: tarfile.TarInfo) -> tarfile.TarInfo | None:
    """A compile cache's member as packed: Warp's CUDA sources (``warp/**/*.cu``; its cache lookup reads only a
    module's binary and ``.meta``) and MathDx's link-time objects (``warp/*/lto/``; needed only to compile a tile
    module again) are left out."""
    name = info.name
    if name.startswith("./warp/") and (name.endswith(".cu") or "/lto/" in name + "/"):
        return None
    return info


def pack(site: Path, out: Path, part_mb: float, name: str = "gpu_site", preset: int = 9 | lzma.PRESET_EXTREME,
         member=None) -> list[Path]:
    """``site`` as a tar.xz split into parts ``<name>.tar.xz.part<k>`` of at most ``part_mb`` MB each;
    ``member``: a tar filter (None leaves a member out)."""
    out.mkdir(parents=True, exist_ok=True)
    archive = out / f"{name}.tar.xz"
    with lzma.open(archive, "wb", preset=preset) as xz, tarfile.open(fileobj=xz, mode="w") as tar:
        tar.add(site, arcname=".", filter=member)
    size = int(part_mb * 1e6)
    parts = []
    with open(archive, "rb") as f:
        while chunk := f.read(size):
            part = out / f"{archive.name}.part{len(parts) + 1}"
            part.write_bytes(chunk)
            parts.append(part)
    archive.unlink()
    return parts


def unpack_line(parts: list[Path], where: str, var: str = "SITE", default: str = "/tmp/gpu_site") -> str:
    """The shell line that joins the parts (looked for in ``where`` on the node) and unpacks them into ``$var``."""
    names = " ".join(f"{where}/{p.name}" for p in parts)
    return f'{var}=${{{var}:-{default}}}; mkdir -p "${var}" && cat {names} | xz -d -T0 | tar -x -C "${var}"'


LEASE_READS = ("docs/policies/gpu/base_h200_resume.pt",)
"""The files under ``docs/`` a lease reads (``tools/gpu_lease.sh``'s default ``TRAIN_FROM``); the rest of ``docs/``
(curves, figures, policies, experiment records) stays behind."""

CALL_LIMIT_MB = 64 * 2**20 / 1e6
"""What one call to the nodes this project is lent carries, working tree included: 64 MiB."""


def lease_tree(repo: Path) -> list[Path]:
    """The tracked files a lease carries: everything outside ``docs/``, and :data:`LEASE_READS`."""
    out = subprocess.run(["git", "ls-files", "-z"], cwd=repo, capture_output=True, check=True).stdout
    files = [f for f in out.decode().split("\0") if f and (not f.startswith("docs/") or f in LEASE_READS)]
    return [repo / f for f in files if (repo / f).is_file()]


def plan_calls(pack_dir: Path, tree_bytes: int, limit_mb: float = CALL_LIMIT_MB) -> list[dict]:
    """The calls of one lease: each carries the tree and one part of the wheels, the last one also the caches'
    parts (``make gpu-caches``); raises :class:`UserError` when a call would exceed ``limit_mb`` or no wheels
    are packed."""
    def parts(name: str) -> list[Path]:
        return sorted(pack_dir.glob(f"{name}.tar.xz.part*"), key=lambda q: int(q.name.rsplit("part", 1)[1]))

    site, caches = parts("gpu_site"), parts("gpu_caches")
    if not site:
        raise UserError(f"no gpu_site.tar.xz.part* in {pack_dir}: run `make gpu-pack` first")
    calls = [[q] for q in site[:-1]] + [[site[-1], *caches]]
    rows = [{"carry": [str(q) for q in call], "mb": (tree_bytes + sum(q.stat().st_size for q in call)) / 1e6}
            for call in calls]
    over = [r for r in rows if r["mb"] > limit_mb]
    if over:
        raise UserError(f"a call would carry {over[0]['mb']:.1f} MB (limit {limit_mb:.1f} MB): "
                        f"{', '.join(over[0]['carry'])} with a {tree_bytes / 1e6:.1f} MB tree; pack smaller parts "
                        "(--part-mb) or carry less")
    return rows


def print_plan(repo: Path, pack_dir: Path, limit_mb: float) -> list[dict]:
    """Print the lease's calls, their sizes and how to leave ``docs/`` behind (git's index) and restore it."""
    tree = lease_tree(repo)
    tree_bytes = sum(f.stat().st_size for f in tree)
    rows = plan_calls(pack_dir, tree_bytes, limit_mb)
    print(f"the tree a lease carries: {len(tree)} tracked files, {tree_bytes / 1e6:.1f} MB (outside docs/, and "
          f"{', '.join(LEASE_READS)}); calls, each at most {limit_mb:.1f} MB:")
    for k, r in enumerate(rows, 1):
        how = "moves its part to /root" if k < len(rows) else "runs tools/gpu_lease.sh"
        print(f"  call {k}: {r['mb']:.1f} MB, carries {' '.join(r['carry'])}; {how}")
    keep = " ".join(LEASE_READS)
    print(f"leave docs/ behind:  git rm -r -q --cached docs && git add -f {keep} && echo /docs/ >> .git/info/exclude\n"
          "restore after:       sed -i '\\#^/docs/$#d' .git/info/exclude && git reset -q")
    return rows


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(prog="dls_quadruped.tools.gpu_pack", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path(".gpu_pack"), help="folder for the parts (created)")
    p.add_argument("--wheels", type=Path, default=None,
                   help="a folder of wheels already downloaded (make wheelhouse); default: download them")
    p.add_argument("--python-version", default="3.12", help="the node's Python (default 3.12)")
    p.add_argument("--exclude", default=NODE_HAS, help=f"distributions the node has (default {NODE_HAS})")
    p.add_argument("--part-mb", type=positive_float, default=48.0, help="largest part in MB (default 48)")
    p.add_argument("--where", default=".gpu_pack", help="where unpack.sh looks for the parts on the node")
    p.add_argument("--caches", type=Path, default=None, metavar="DIR",
                   help="pack this compile-cache folder (warp/, inductor/) instead of the wheels")
    p.add_argument("--plan", action="store_true",
                   help="print the calls of a lease (the tree and the parts in --out, each call's size) and stop")
    p.add_argument("--limit-mb", type=positive_float, default=CALL_LIMIT_MB,
                   help=f"what one call carries (default {CALL_LIMIT_MB:.1f} MB = 64 MiB)")
    args = p.parse_args(argv)
    if args.plan:
        print_plan(Path(__file__).resolve().parents[2], args.out, args.limit_mb)
        return
    if args.caches is not None:
        if not args.caches.is_dir():
            p.error(f"--caches {args.caches} is not a folder")
        for old in args.out.glob("gpu_caches.tar.xz.part*") if args.out.exists() else ():
            old.unlink()
        parts = pack(args.caches, args.out, args.part_mb, "gpu_caches", preset=6, member=warp_cache_member)
        line = unpack_line(parts, args.where, "CACHES", "/tmp/gpu_caches")
        (args.out / "unpack_caches.sh").write_text(line + "\n")
        print(f"{args.caches} -> {sum(q.stat().st_size for q in parts) / 1e6:.1f} MB xz in {len(parts)} part(s) in "
              f"{args.out}; on the node:\n  {line}\n  export WARP_CACHE_PATH=$CACHES/warp "
              f"TORCHINDUCTOR_CACHE_DIR=$CACHES/inductor")
        return
    with tempfile.TemporaryDirectory() as tmp:
        wheels = args.wheels
        if wheels is None:
            wheels = Path(tmp) / "wheels"
            wheelhouse.main(["--out", str(wheels), "--python-version", args.python_version,
                             "--exclude", args.exclude])
        elif not wheels.is_dir():
            p.error(f"--wheels {wheels} is not a folder (make wheelhouse WHEELHOUSE={wheels})")
        site = Path(tmp) / "site"
        names = unpack(wheels, site)
        if not names:
            p.error(f"no wheels in {wheels}")
        unpacked = sum(f.stat().st_size for f in site.rglob("*") if f.is_file())
        if args.out.exists():
            for old in args.out.glob("gpu_site.tar.xz.part*"):
                old.unlink()
        parts = pack(site, args.out, args.part_mb)
    line = unpack_line(parts, args.where)
    (args.out / "unpack.sh").write_text(line + "\n")
    packed = sum(q.stat().st_size for q in parts)
    print(f"{len(names)} wheels, {unpacked / 1e6:.0f} MB unpacked -> {packed / 1e6:.1f} MB xz in {len(parts)} "
          f"part(s) of <= {args.part_mb:g} MB in {args.out}; on the node:\n  {line}\n"
          f"  export PYTHONPATH=$SITE:$PYTHONPATH")


if __name__ == "__main__":
    run_cli(main)
