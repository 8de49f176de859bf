"""``python -m dls_quadruped.bench.mpc_warp``: rows, check, skips and JSON at tiny sizes on Warp's CPU device, and the
command's import closure on a machine with only torch, numpy and Warp (the GPU node)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("warp")

from dls_quadruped.bench import mpc_warp

REPO = Path(__file__).resolve().parents[2]


def test_tiny_grid_writes_rows_check_and_skips(tmp_path, capsys):
    out = tmp_path / "mpc_warp.json"
    assert mpc_warp.main(["--device", "cpu", "--samples", "64", "200", "--robots", "1", "2", "--solves", "3",
                          "--point-s", "0.05", "--max-work", "300", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    check = data["machine"]["check"]
    assert check["max_rel_vs_reference"] < 1e-5 and check["argmin_same_as_reference"] == 1.0
    assert check["captured_equals_launched"] is True
    rows = {(r["kernel"], r["B"], r["M"]): r for r in data["results"]}
    assert set(rows) == {(k, b, m) for k in ("warp", "cpp") for b in (1, 2) for m in (64, 200)}
    assert "max-work" in rows[("warp", 2, 200)]["skipped"]  # B M = 400 > 300
    warp = rows[("warp", 2, 64)]
    assert warp["solve_ms"] > 0 and warp["graph_ms"] > 0 and warp["captured"] is True
    assert warp["launches_per_solve"] == 4  # clean, rollout, one argmin level (64 -> 2), decode
    assert rows[("cpp", 1, 200)]["graph_ms"] is None and rows[("cpp", 1, 200)]["solve_ms"] > 0
    printed = capsys.readouterr().out
    assert "| cpu | warp | 2 | 64 |" in printed and f"wrote {out}" in printed


def test_budget_skips_the_rest(tmp_path):
    out = tmp_path / "b.json"
    mpc_warp.main(["--device", "cpu", "--samples", "32", "64", "--robots", "1", "--no-cpp", "--no-check",
                   "--solves", "3", "--budget-s", "1e-9", "--out", str(out)])
    rows = json.loads(out.read_text())["results"]
    assert "solve_ms" in rows[0] and rows[1]["skipped"] == "over --budget-s"


def test_bad_device_is_one_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        mpc_warp.main(["--device", "tpu"])
    assert exit_.value.code == 2 and "--device" in capsys.readouterr().err


BLOCKER = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("mujoco", "mujoco_warp", "pinocchio", "rsl_rl", "yaml", "tensordict", "matplotlib"):
            raise ImportError("not on the GPU node: " + name)
sys.meta_path.insert(0, Block())
sys.modules.pop("yaml", None)
from dls_quadruped.bench import mpc_warp
assert mpc_warp.srbd_model()[1] == "ALIENGO_SRBD (no MuJoCo)"
mpc_warp.main(["--device", "cpu", "--samples", "64", "--robots", "1", "--no-cpp", "--solves", "2",
               "--out", sys.argv[1]])
print(sorted(m.split(".")[0] for m in sys.modules if m.split(".")[0] in ("mujoco", "yaml", "pinocchio")))
"""


def test_runs_without_mujoco_yaml_or_rsl_rl(tmp_path):
    """The GPU node has torch, numpy and Warp only: the command imports nothing else and uses the stored model."""
    from dls_quadruped.mpc.srbd import robot_srbd_model

    assert robot_srbd_model() == mpc_warp.ALIENGO_SRBD or all(
        abs(a - b) < 1e-12 for a, b in zip(_flat(robot_srbd_model()), _flat(mpc_warp.ALIENGO_SRBD), strict=True))
    out = tmp_path / "gpu_node.json"
    proc = subprocess.run([sys.executable, "-c", BLOCKER, str(out)], capture_output=True, text=True, cwd=REPO,
                          env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin", "HOME": str(Path.home())},
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().splitlines()[-1] == "[]"
    assert json.loads(out.read_text())["results"][0]["solve_ms"] > 0


def _flat(model) -> list[float]:
    return [model.mass, *(v for row in model.inertia_b for v in row), *model.com_offset_b, model.gravity]


def test_prediction_is_fixed_cost_plus_cost_per_sample():
    rows = [{"B": 1, "M": 1000, "solve_ms": 0.2}, {"B": 1, "M": 11000, "solve_ms": 0.3}]  # 1e-5 ms per sample
    assert mpc_warp.predict_s([], 10**9) == 0.0
    assert mpc_warp.predict_s(rows[:1], 10**6) == pytest.approx(8 * 0.2e-3)  # one point: its time, no growth
    assert mpc_warp.predict_s(rows, 1_011_000) == pytest.approx(8e-3 * (0.3 + 1e-5 * 1_000_000))
