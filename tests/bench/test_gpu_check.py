"""bench/gpu_check.py: the report is written section by section, a broken section is recorded and the check goes
on, bad arguments are usage errors; on warp-cpu (slow, needs the [gpu] extra) the real sections run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dls_quadruped.bench import gpu_check as G


@pytest.fixture
def fake_mujoco_warp(monkeypatch):
    """An importable stand-in, so the orchestration runs where the [gpu] extra is not installed (CI)."""
    import sys
    import types

    monkeypatch.setitem(sys.modules, "mujoco_warp", types.ModuleType("mujoco_warp"))


def test_a_failing_section_is_recorded_and_the_next_one_runs(tmp_path: Path, monkeypatch, fake_mujoco_warp):
    seen = []

    def boom(*a, **k):
        seen.append("compile")
        raise RuntimeError("kernel compile failed")

    def versions(device):
        seen.append("versions")
        assert json.loads((tmp_path / "report.json").read_text())["sections"] == {}  # nothing written yet
        return {"gpu": "none"}

    monkeypatch.setattr(G, "versions", versions)
    monkeypatch.setattr(G, "compile_times", boom)
    monkeypatch.setattr(G, "trajectories", lambda backend: {"standing": {"ok": True}})
    (tmp_path / "report.json").write_text(json.dumps({"sections": {}}))
    G.main(["--device", "cpu", "--out", str(tmp_path),
            "--skip", "graph,syncs,launches,faults,env,gpu_busy,mpc,rough,train"])
    rep = json.loads((tmp_path / "report.json").read_text())
    assert seen == ["versions", "compile"]
    assert rep["device"] == "cpu" and rep["backend"] == "warp-cpu"
    assert rep["sections"]["versions"]["gpu"] == "none"
    assert "RuntimeError: kernel compile failed" in rep["sections"]["compile"]["error"]
    assert rep["sections"]["trajectories"]["standing"]["ok"] is True
    assert set(rep["sections"]) == {"versions", "compile", "trajectories"}


def test_sections_past_the_budget_are_marked_skipped(tmp_path: Path, monkeypatch, fake_mujoco_warp):
    monkeypatch.setattr(G, "versions", lambda device: {"gpu": "none"})
    G.main(["--device", "cpu", "--out", str(tmp_path), "--budget-s", "30", "--skip", "train"])
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["sections"]["compile"] == {"skipped": "budget"} and rep["sections"]["mpc"] == {"skipped": "budget"}


@pytest.mark.parametrize("argv, message", [(["--skip", "warmup"], "unknown sections ['warmup']"),
                                           (["--device", "mps"], "--device must be cuda or cpu")])
def test_bad_arguments_are_usage_errors(tmp_path: Path, capsys, argv, message, fake_mujoco_warp):
    with pytest.raises(SystemExit) as err:
        G.main(["--out", str(tmp_path), *argv])
    assert err.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.slow
def test_the_check_runs_on_warp_cpu(tmp_path: Path):
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    G.main(["--device", "cpu", "--out", str(tmp_path), "--skip", "compile,mpc,train", "--budget-s", "3000"])
    rep = json.loads((tmp_path / "report.json").read_text())["sections"]
    for name in ("standing", "trot"):  # the same algorithm as the committed warp-cpu run
        assert rep["trajectories"][name]["vs_warp-cpu"]["ok"], rep["trajectories"][name]
        assert rep["trajectories"][name]["vs_cpu"]["ok"], rep["trajectories"][name]
    assert rep["syncs"]["syncs_per_step_max"] == 0  # no Warp array read inside env.step
    fused, eager = rep["launches"]["compiled"], rep["launches"]["eager"]
    assert fused["compiled"] and fused["torch_ops_per_step"] <= 300 < eager["torch_ops_per_step"]
    # on the CPU: base at the CPU default of scene.compile (None) and with it off, then rough
    rows = rep["env"]["rows"] + rep["rough"]["rows"]
    assert [(r["task"], r["captured"], r["compiled"]) for r in rows] == [("base", True, None), ("base", True, False),
                                                                          ("rough", True, None)]
    assert all(r["steps_per_s"] > 0 and "capture_errors" not in r for r in rows)
    assert rep["syncs"]["warmup"] == 3
    assert rep["faults"]["all_reset"] and rep["faults"]["finite"] and rep["faults"]["others_reset"] == 0
    assert rep["faults"]["others_max_abs_diff"] <= 1e-5  # the worlds share MuJoCo Warp's contact buffer
    # the step replayed from one graph (emulated on warp-cpu): as the eager step bit for bit, then timed beside it
    agree = rep["graph"]["agreement"]
    assert (agree["captures"], agree["replays"], agree["error"]) == (1, 8 - 1 - 3, None)
    assert agree["max_base_pos_diff_m"] == {"eager_vs_eager": 0.0, "graph_vs_eager": 0.0,
                                            "graph_vs_eager_first_10_replays": 0.0}
    assert agree["differing_dones"] == {"eager_vs_eager": 0, "graph_vs_eager": 0}
    graph_rows = rep["graph"]["rows"]
    assert [r["cuda_graph"] for r in graph_rows] == [True, False] and all(r["steps_per_s"] > 0 for r in graph_rows)
    assert graph_rows[0]["step_graph"] == {"captures": 1, "replays": 2, "error": None}


def test_without_mujoco_warp_it_is_a_one_line_usage_error(tmp_path: Path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "mujoco_warp", None)  # import mujoco_warp -> ImportError
    with pytest.raises(SystemExit) as err:
        G.main(["--device", "cpu", "--out", str(tmp_path)])
    msg = capsys.readouterr().err
    assert err.value.code == 2 and "mujoco_warp is not installed: make install-gpu" in msg


def test_ppo_throughput_is_the_median_iteration_after_the_first():
    rows = ["iteration,mean_reward,collection_s,learning_s", "0,0,58.0,0.5",  # the first compiles: left out
            "1,0,0.5,0.25", "2,0,0.6,0.2", "3,0,30.0,0.2", "4,0,0.55,0.25"]
    got = G.ppo_throughput(rows, num_envs=4096)
    # iterations 1-4: 0.75, 0.8, 30.2, 0.8 -> median (0.8 + 0.8) / 2 = 0.8 s; 4096 x 24 / 0.8 = 122 880 samples/s
    assert got["iteration_s_median"] == pytest.approx(0.8)
    assert got["samples_per_s"] == pytest.approx(122880.0)


def test_fault_trials_reset_the_faulty_robots_and_leave_the_others_bit_identical():
    """On the CPU backend (the same function the GPU check runs on cuda and warp-cpu): NaN, +inf and -inf action
    rows and a 5 km/s push each reset their robot, nothing non-finite reaches an observation, and the four other
    robots' observations equal those of the same env without faults, bit for bit."""
    import torch

    from dls_quadruped.bench.gpu_probes import FAULTY, faults

    rep = faults("cpu", torch.device("cpu"))
    assert rep["reset"] == {name: True for name in FAULTY}
    assert rep["finite"] and rep["others_reset"] == 0 and rep["others_max_abs_diff"] == 0.0
    assert rep["sim_diverged"] == [FAULTY["diverged_push"]] and rep["sim_diverged_logged"] == 1.0


@pytest.mark.slow
def test_a_world_that_overflows_its_constraint_rows_is_reset_and_counted_on_warp_cpu():
    """On warp-cpu the trials add a robot sunk 5 cm into the ground (every link penetrating: 96 constraint rows, over
    base's njmax of 64): MuJoCo Warp flags its world alone, the backend flags the robot diverged, ``sim_diverged``
    ends and counts it with the pushed one, and the other robots run bit for bit as without the faults (the contact
    buffer they share did not overflow)."""
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    import torch

    from dls_quadruped.bench.gpu_probes import FAULTY, WARP_FAULTY, faults

    rep = faults("warp-cpu", torch.device("cpu"))
    row = WARP_FAULTY["contact_overflow"]
    assert rep["overflowed"] == [row] and rep["reset"] == {name: True for name in {**FAULTY, **WARP_FAULTY}}
    assert rep["sim_diverged"] == sorted([FAULTY["diverged_push"], row]) and rep["sim_diverged_logged"] == 2.0
    assert rep["finite"] and rep["others_reset"] == 0 and rep["others_max_abs_diff"] == 0.0


def test_fault_trials_need_more_robots_than_faults():
    import torch

    from dls_quadruped.bench.gpu_probes import faults

    with pytest.raises(ValueError, match="num_envs must be > 4, got 4"):
        faults("cpu", torch.device("cpu"), num_envs=4)


def test_train_section_passes_the_graph_setting_to_the_trainer(tmp_path: Path, monkeypatch):
    """``--train-graph``: the training run steps its env from one CUDA graph (``scene.cuda_graph``); without it the
    setting is passed off explicitly, so a report says which it measured."""
    import torch

    cmds = []

    class _Proc:
        returncode = 0

        def __init__(self, cmd, **_):
            cmds.append(cmd)

        def wait(self, timeout=None):
            return 0

    monkeypatch.setattr(G.subprocess, "Popen", _Proc)
    for graph in (True, False):
        got = G.train(torch.device("cpu"), "warp-cpu", 8, 1.0, tmp_path, 1, cuda_graph=graph)
        assert got["cuda_graph"] is graph and got["returncode"] == 0
    assert [c[c.index("--set") + 1] for c in cmds] == ["scene.cuda_graph=true", "scene.cuda_graph=false"]
