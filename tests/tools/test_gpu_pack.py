"""tools/gpu_pack.py: wheels unpacked into one import folder (Warp's CPU compiler left out), packed with xz in
parts of a given size, and the shell line that puts them back together on the node."""

from __future__ import annotations

import os
import subprocess
import tarfile
import zipfile
from pathlib import Path

import pytest

from dls_quadruped.tools import gpu_pack


def _wheel(folder: Path, name: str, files: dict[str, bytes]) -> None:
    with zipfile.ZipFile(folder / name, "w") as z:
        for path, data in files.items():
            z.writestr(path, data)


@pytest.fixture
def wheels(tmp_path):
    folder = tmp_path / "wheels"
    folder.mkdir()
    noise = os.urandom(20_000)  # incompressible: the archive needs several 4 kB parts
    _wheel(folder, "warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl",
           {"warp/__init__.py": b"x = 1\n", "warp/bin/warp.so": noise, "warp/bin/warp-clang.so": b"llvm",
            "warp/examples/demo.py": b"pass\n"})
    _wheel(folder, "rsl_rl_lib-5.5.1-py3-none-any.whl", {"rsl_rl/__init__.py": b"", "rsl_rl-5.5.1.dist-info/M": b"m"})
    _wheel(folder, "dls_quadruped-0.1.0-py3-none-any.whl", {"dls_quadruped/__init__.py": b""})  # runs from the tree
    return folder


def test_pack_then_unpack_line_gives_the_wheels_back_without_warp_clang(wheels, tmp_path):
    out = tmp_path / "pack"
    gpu_pack.main(["--wheels", str(wheels), "--out", str(out), "--part-mb", "0.004", "--where", str(out)])
    parts = sorted(out.glob("gpu_site.tar.xz.part*"), key=lambda p: int(p.name.rsplit("part", 1)[1]))
    assert len(parts) >= 5 and all(p.stat().st_size <= 4000 for p in parts)
    line = (out / "unpack.sh").read_text().strip()
    site = tmp_path / "site"
    subprocess.run(["bash", "-c", line], env={**os.environ, "SITE": str(site)}, check=True)
    got = {str(p.relative_to(site)) for p in site.rglob("*") if p.is_file()}
    assert got == {"warp/__init__.py", "warp/bin/warp.so", "rsl_rl/__init__.py", "rsl_rl-5.5.1.dist-info/M"}
    with zipfile.ZipFile(next(wheels.glob("warp_lang*"))) as z:
        assert (site / "warp/bin/warp.so").read_bytes() == z.read("warp/bin/warp.so")


def test_a_missing_wheel_folder_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        gpu_pack.main(["--wheels", str(tmp_path / "nowhere"), "--out", str(tmp_path / "pack")])
    assert exc.value.code == 2 and "--wheels" in capsys.readouterr().err


def test_a_cache_folder_round_trips(tmp_path):
    caches = tmp_path / "caches"
    (caches / "warp" / "k1").mkdir(parents=True)
    (caches / "warp" / "k1" / "module.cubin").write_bytes(os.urandom(9000))
    (caches / "warp" / "k1" / "module.cu").write_text("// the source: left out")
    (caches / "warp" / "1.19.0" / "lto").mkdir(parents=True)
    (caches / "warp" / "1.19.0" / "lto" / "a.lto").write_bytes(b"mathdx: left out")
    (caches / "inductor").mkdir()
    (caches / "inductor" / "fx.bin").write_bytes(b"graph")
    (caches / "inductor" / "kernel.cu").write_text("// not Warp's: kept")
    out = tmp_path / "pack"
    gpu_pack.main(["--caches", str(caches), "--out", str(out), "--part-mb", "0.004", "--where", str(out)])
    line = (out / "unpack_caches.sh").read_text().strip()
    assert line.startswith("CACHES=${CACHES:-/tmp/gpu_caches}")
    back = tmp_path / "back"
    subprocess.run(["bash", "-c", line], env={**os.environ, "CACHES": str(back)}, check=True)
    for rel in ("warp/k1/module.cubin", "inductor/fx.bin", "inductor/kernel.cu"):
        assert (back / rel).read_bytes() == (caches / rel).read_bytes()
    assert not (back / "warp/k1/module.cu").exists() and not (back / "warp/1.19.0/lto").exists()


def test_the_lease_script_unpacks_carried_caches_and_says_which_kernels_the_node_compiled(tmp_path):
    """``tools/gpu_lease.sh`` with no sections (nothing needs a GPU): the carried caches (``make gpu-caches``) are
    unpacked before anything runs, a Warp module written during the lease counts as compiled on the node, the
    carried one as carried, and the caches go back in parts."""
    repo = Path(__file__).resolve().parents[2]
    caches = tmp_path / "carried"
    old = caches / "warp" / "1.19.0" / "wp_a_1234567"
    old.mkdir(parents=True)
    (old / "wp_a_1234567.sm90.cubin").write_bytes(os.urandom(3000))
    pack = tmp_path / "pack"
    gpu_pack.main(["--caches", str(caches), "--out", str(pack), "--part-mb", "0.002", "--where", str(pack)])
    assert len(list(pack.glob("gpu_caches.tar.xz.part*"))) >= 2
    site, node, out = tmp_path / "site", tmp_path / "node", tmp_path / "out"
    (site / "warp").mkdir(parents=True)  # the wheels already unpacked: the script skips them
    out.mkdir()
    # a stand-in `python` on PATH that "compiles" one more module whenever the script runs Python
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    new = node / "warp" / "1.19.0" / "wp_b_7654321"
    (bin_ / "python").write_text(f"#!/bin/sh\nmkdir -p {new} && touch {new}/wp_b_7654321.sm90.cubin "
                                 f"{new}/wp_b_7654321.cu\n")
    (bin_ / "python").chmod(0o755)
    env = {**os.environ, "OUT": str(out), "PACK": str(pack), "SITE": str(site), "CACHES": str(node),
           "SECTIONS": "", "LEASE_S": "60", "PATH": f"{bin_}:{os.environ['PATH']}"}
    run = subprocess.run(["bash", str(repo / "dls_quadruped/tools/gpu_lease.sh")], cwd=repo, env=env,
                         capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stdout + run.stderr
    with tarfile.open(out / "results.tar") as tar:  # the small results come back in one tar
        sizes = tar.extractfile("./cache_sizes.txt").read().decode()
    assert "compiled on the node: 1, carried: 1" in sizes and "wp_b_7654321.sm90.cubin" in sizes, sizes
    assert (node / "warp/1.19.0/wp_a_1234567/wp_a_1234567.sm90.cubin").read_bytes() == \
        (old / "wp_a_1234567.sm90.cubin").read_bytes()
    parts = sorted(out.glob("gpu_caches.tar.xz.part*"))
    names = subprocess.run(f"cat {' '.join(map(str, parts))} | xz -d | tar -t", shell=True, check=True,
                           capture_output=True, text=True).stdout.split()
    assert "./warp/1.19.0/wp_b_7654321/wp_b_7654321.sm90.cubin" in names, names
    assert "./warp/1.19.0/wp_a_1234567/wp_a_1234567.sm90.cubin" in names
    assert not [n for n in names if n.endswith(".cu")]  # Warp's sources stay behind


def _parts(folder: Path, name: str, sizes: list[int]) -> None:
    folder.mkdir(exist_ok=True)
    for k, size in enumerate(sizes, 1):
        (folder / f"{name}.tar.xz.part{k}").write_bytes(b"x" * size)


def test_a_lease_carries_one_wheel_part_per_call_and_the_caches_with_the_last(tmp_path):
    _parts(tmp_path, "gpu_site", [1000, 1000, 700])
    _parts(tmp_path, "gpu_caches", [200])
    rows = gpu_pack.plan_calls(tmp_path, tree_bytes=500, limit_mb=0.0015)
    assert [[Path(c).name for c in r["carry"]] for r in rows] == [
        ["gpu_site.tar.xz.part1"], ["gpu_site.tar.xz.part2"], ["gpu_site.tar.xz.part3", "gpu_caches.tar.xz.part1"]]
    assert [r["mb"] for r in rows] == [0.0015, 0.0015, 0.0014]


def test_a_call_over_the_limit_or_no_wheels_is_refused(tmp_path):
    _parts(tmp_path, "gpu_site", [1_000_000, 900_000])
    _parts(tmp_path, "gpu_caches", [200_000])
    assert len(gpu_pack.plan_calls(tmp_path, tree_bytes=400_000, limit_mb=1.5)) == 2
    with pytest.raises(gpu_pack.UserError, match=r"a call would carry 1.6 MB \(limit 1.5 MB\): .*part2"):
        gpu_pack.plan_calls(tmp_path, tree_bytes=500_000, limit_mb=1.5)
    with pytest.raises(gpu_pack.UserError, match="make gpu-pack"):
        gpu_pack.plan_calls(tmp_path / "empty", tree_bytes=0)


def test_the_tree_a_lease_carries_is_the_code_and_what_the_lease_reads_under_8_mb():
    """What a GPU job needs of the tracked tree stays under 8 MB (the checkpoint it continues from
    aside); docs/ stays behind but for the files the lease reads."""
    repo = Path(__file__).resolve().parents[2]
    tree = {str(f.relative_to(repo)) for f in gpu_pack.lease_tree(repo)}
    assert {"Makefile", "dls_quadruped/tools/gpu_lease.sh", "tasks/base.yaml", *gpu_pack.LEASE_READS} <= tree
    assert not [f for f in tree if f.startswith("docs/") and f not in gpu_pack.LEASE_READS]
    code = sum((repo / f).stat().st_size for f in tree if f not in gpu_pack.LEASE_READS)
    assert code < 8e6, f"{code / 1e6:.1f} MB"


def test_the_plan_prints_each_call_and_how_to_leave_docs_behind(tmp_path, capsys):
    _parts(tmp_path, "gpu_site", [1000, 900])
    gpu_pack.main(["--plan", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert "call 1: " in out and "moves its part to /root" in out and "call 2: " in out
    assert "git rm -r -q --cached docs && git add -f docs/policies/gpu/base_h200_resume.pt" in out
    assert "git reset -q" in out
