"""GCC's vectoriser report on the C++ MPC kernel: every 16-lane loop vectorises without AVX-512.

AVX-512 turns per-lane control flow into masked instructions, so a kernel can look vectorised on an
AVX-512 machine and run scalar everywhere else (issue 15). The kernel is compiled here, without
linking, for x86-64-v3 (AVX2 + FMA) and armv8-a (NEON, with the cross-compiler where installed) with
the flags of the real build plus ``-fopt-info-vec-optimized -fopt-info-vec-missed``, and each loop
``for (int l = 0; l < L; ++l)`` must be reported "loop vectorized" at its line. A compile without
auto-vectorisation checks that the report parsing does see a loop that is not vectorised.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from dls_quadruped.mpc import cpp_kernel

LANE_LOOP = "for (int l = 0; l < L; ++l)"
VECTORISED = re.compile(r"rollout_kernel\.cpp:(\d+):\d+: optimized: loop vectorized using (\d+) byte vectors")


def lane_loop_lines() -> list[int]:
    """1-based line numbers of the lane loops in rollout_kernel.cpp (comments excluded)."""
    lines = cpp_kernel.SOURCE.read_text().splitlines()
    found = [i + 1 for i, line in enumerate(lines) if LANE_LOOP in line.split("//")[0]]
    assert all(lines[n - 1].count("for (") == 1 for n in found)  # one loop per line: the report's line names it
    return found


def _target(cxx: str) -> str:
    return subprocess.run([cxx, "-dumpmachine"], capture_output=True, text=True, check=False).stdout.strip()


def vectorised_loops(cxx: str, flags: list[str], tmp_path: Path) -> dict[int, int]:
    """{line: vector bytes} of the loops GCC reports vectorised when compiling the kernel with ``flags``."""
    cmd = [cxx, *flags, *cpp_kernel.COMMON_FLAGS, *cpp_kernel.extra_flags(cxx), "-fopt-info-vec-optimized",
           "-fopt-info-vec-missed", "-c", str(cpp_kernel.SOURCE), "-o", str(tmp_path / "kernel.o")]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return {int(m[1]): int(m[2]) for m in VECTORISED.finditer(proc.stderr)}


def _x86_gcc() -> str:
    cxx = shutil.which("g++")
    if cxx is None or not _target(cxx).startswith("x86_64"):
        pytest.skip("needs g++ targeting x86_64 (none on PATH)")
    return cxx


def _aarch64_gcc() -> str:
    for name in ("aarch64-linux-gnu-g++", "g++"):
        cxx = shutil.which(name)
        if cxx is not None and _target(cxx).startswith("aarch64"):
            return cxx
    pytest.skip("no AArch64 g++ (apt-get install g++-aarch64-linux-gnu): the NEON report is not checked")


def test_lane_loops_are_found():
    lines = lane_loop_lines()
    # padding, group check, draw, centre + clip (3), state init, decode, contacts, dynamics + cost, NaN -> inf
    assert len(lines) >= 11, lines


def test_every_lane_loop_vectorises_with_avx2(tmp_path):
    cxx = _x86_gcc()
    flags = cpp_kernel.flag_sets("x86-64-v3")[0]
    assert "-march=x86-64-v3" in flags
    loops = vectorised_loops(cxx, flags, tmp_path)
    missing = [n for n in lane_loop_lines() if n not in loops]
    assert not missing, f"lane loops not vectorised for x86-64-v3 at rollout_kernel.cpp lines {missing}"
    assert {loops[n] for n in lane_loop_lines()} == {32}  # 8 float lanes of AVX2, not AVX-512's 64 bytes


def test_report_sees_unvectorised_loops(tmp_path):
    """The comparison build of the benchmark: no lane loop vectorised (so the check above can fail)."""
    cxx = _x86_gcc()
    flags = [f for f in cpp_kernel.flag_sets("x86-64-v3")[0]] + cpp_kernel.NO_VECTORISE
    loops = vectorised_loops(cxx, flags, tmp_path)
    assert not set(loops) & set(lane_loop_lines())
    assert cpp_kernel.flag_sets("scalar")[0][-2:] == cpp_kernel.NO_VECTORISE


def test_every_lane_loop_vectorises_with_neon(tmp_path):
    cxx = _aarch64_gcc()
    flags = [f if not f.startswith("-march=") else "-march=armv8-a" for f in cpp_kernel.flag_sets("x86-64-v3")[0]]
    loops = vectorised_loops(cxx, flags, tmp_path)
    missing = [n for n in lane_loop_lines() if n not in loops]
    assert not missing, f"lane loops not vectorised for armv8-a at rollout_kernel.cpp lines {missing}"
    assert {loops[n] for n in lane_loop_lines()} == {16}  # 4 float lanes of NEON
