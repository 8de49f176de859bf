"""Download every wheel an install of this package needs, for another Python and platform, into one folder.

``make wheelhouse`` (= ``python -m dls_quadruped.tools.wheelhouse``) is the route to an air-gapped GPU node: on
a machine with network, the closure of ``dls_quadruped[gpu]`` (or other extras) is resolved from the
distributions installed in *this* environment (so the versions are the tested ones), each ``name==version`` is
downloaded with ``pip download --no-deps --only-binary=:all:`` for the target Python (default cp312) and
platform (default manylinux x86_64), and a wheel of this package is built beside them. On the node,
``make install-offline WHEELHOUSE=...`` installs from the folder with ``--no-index``.

``--exclude`` drops distributions the target already has (e.g. its own CUDA torch) together with whatever only
they need, so a folder for a machine with torch preinstalled does not carry several GB of CUDA libraries.
"""

from __future__ import annotations

import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement

from dls_quadruped.cli import ArgumentParser, run_cli

MANYLINUX_X86_64 = ("manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux_2_27_x86_64",
                    "manylinux_2_28_x86_64", "manylinux_2_34_x86_64", "manylinux1_x86_64", "any")
"""Platform tags pip may match for a glibc x86-64 Linux node (pip matches each tag exactly)."""


def canonical(name: str) -> str:
    """PEP 503 normalised distribution name (``Rsl_RL.lib`` -> ``rsl-rl-lib``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _applies(req: Requirement, extras: set[str], python_version: str) -> bool:
    """Whether ``req``'s marker holds on the target (its Python version, Linux, the requested extras)."""
    if req.marker is None:
        return True
    env = {**default_environment(), "python_version": python_version, "python_full_version": f"{python_version}.0",
           "sys_platform": "linux", "platform_system": "Linux", "os_name": "posix", "platform_machine": "x86_64",
           "implementation_name": "cpython", "platform_python_implementation": "CPython"}
    return any(req.marker.evaluate({**env, "extra": e}) for e in (extras | {""}))


def closure(root: str, extras: set[str], exclude: set[str], python_version: str) -> dict[str, str]:
    """``{name: version}`` of every installed distribution ``root[extras]`` needs, not descending into ``exclude``.

    Raises:
        RuntimeError: a needed distribution is not installed here (install it first: the versions come from here).
    """
    found: dict[str, str] = {}
    todo = [(root, extras)]
    while todo:
        name, want = todo.pop()
        key = canonical(name)
        if key in exclude or (key in found and not want):
            continue
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            raise RuntimeError(f"{name} is needed but not installed in this environment; install it first "
                               "(make install-gpu), the wheelhouse takes the installed versions") from None
        found[key] = dist.version
        for line in dist.requires or []:
            req = Requirement(line)
            if _applies(req, want, python_version):
                todo.append((req.name, set(req.extras)))
    return found


def download(pins: dict[str, str], dest: Path, python_version: str, platforms: tuple[str, ...]) -> None:
    """``pip download --no-deps`` of each ``name==version`` as a binary wheel for the target into ``dest``."""
    plat = [a for p in platforms for a in ("--platform", p)]
    impl = ["--python-version", python_version.replace(".", ""), "--implementation", "cp"]
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "-d", str(dest),
           *impl, *plat, *(f"{n}=={v}" for n, v in sorted(pins.items()))]
    subprocess.run(cmd, check=True)


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(prog="dls_quadruped.tools.wheelhouse", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("wheelhouse"), help="folder for the wheels (created)")
    p.add_argument("--extras", default="gpu", help="comma-separated extras of dls_quadruped (default gpu)")
    p.add_argument("--python-version", default="3.12", help="target Python, e.g. 3.11 or 3.12 (default 3.12)")
    p.add_argument("--platform", action="append", default=None,
                   help="pip platform tag (repeatable; default: glibc manylinux x86_64 tags)")
    p.add_argument("--exclude", default="", help="comma-separated distributions the target already has")
    p.add_argument("--list", action="store_true", help="print the pinned closure and download nothing")
    args = p.parse_args(argv)
    if not re.fullmatch(r"3\.\d+", args.python_version):
        p.error(f"--python-version must look like 3.12, got {args.python_version!r}")
    extras = {e.strip() for e in args.extras.split(",") if e.strip()}
    exclude = {canonical(e) for e in args.exclude.split(",") if e.strip()}
    pins = closure("dls_quadruped", extras, exclude, args.python_version)
    pins.pop("dls-quadruped")
    if args.list:
        print("\n".join(f"{n}=={v}" for n, v in sorted(pins.items())))
        return
    args.out.mkdir(parents=True, exist_ok=True)
    download(pins, args.out, args.python_version, tuple(args.platform or MANYLINUX_X86_64))
    root = Path(__file__).resolve().parents[2]
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                    str(args.out), str(root)], check=True)
    print(f"{len(pins) + 1} wheels in {args.out} for CPython {args.python_version}; install with "
          f"make install-offline WHEELHOUSE={args.out}")


if __name__ == "__main__":
    run_cli(main)
