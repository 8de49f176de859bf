"""tools/gpu_pack.py: wheels unpacked into one import folder (Warp's CPU compiler left out), packed with xz in
parts of a given size, and the shell line that puts them back together on the node."""

from __future__ import annotations

import os
import subprocess
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
    (caches / "inductor").mkdir()
    (caches / "inductor" / "fx.bin").write_bytes(b"graph")
    out = tmp_path / "pack"
    gpu_pack.main(["--caches", str(caches), "--out", str(out), "--part-mb", "0.004", "--where", str(out)])
    line = (out / "unpack_caches.sh").read_text().strip()
    assert line.startswith("CACHES=${CACHES:-/tmp/gpu_caches}")
    back = tmp_path / "back"
    subprocess.run(["bash", "-c", line], env={**os.environ, "CACHES": str(back)}, check=True)
    for rel in ("warp/k1/module.cubin", "inductor/fx.bin"):
        assert (back / rel).read_bytes() == (caches / rel).read_bytes()
