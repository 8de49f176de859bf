"""docs/workflow.md's train -> play -> choose -> evaluate -> compare steps, run for real at tiny sizes, each
step consuming what the one before wrote, the compare step with the page's own command line (the distillation
and closed-loop steps at tiny sizes are tests/learning/test_distill_cli.py::test_tiny_run_resume_and_outputs and
tests/closed_loop/test_closed_loop.py::test_cli_writes_summary; every command of the page is checked against
argparse and the Makefile by tests/test_docs_commands.py)."""

from __future__ import annotations

import json
from pathlib import Path

from dls_quadruped.eval import select
from dls_quadruped.eval.__main__ import default_out
from dls_quadruped.eval.__main__ import main as eval_main
from dls_quadruped.eval.compare import main as compare_main
from dls_quadruped.learning import play, train

TINY = ["--num-workers", "0"]
REPO = Path(__file__).resolve().parents[1]


def test_train_play_select_evaluate_compare(tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    # 1. train (make train TASK=base), tiny: 2 iterations of 4 robots
    run = train.main(["--task", "base", "--num-envs", "4", "--iterations", "2", "--save-interval", "1",
                      "--log-root", str(runs), *TINY])
    assert sorted(p.name for p in run.glob("model_*.pt")) == ["model_0.pt", "model_1.pt"]
    assert (run / "exported" / "policy.pt2").is_file()
    # 2. play the newest checkpoint of the latest run (make play TASK=base)
    played = play.main(["--task", "base", "--log-root", str(runs), "--seconds", "0.2", "--num-envs", "1", "--no-video",
                        *TINY])
    assert played == run / "play" and (played / "play.npz").is_file()  # beside model_1.pt, the newest
    # 3. choose a checkpoint on validation episodes (make select RUN=...)
    chosen = select.main([str(run), "--episodes", "2", "--num-workers", "0"])
    assert chosen["split"] == "validation" and {c["iteration"] for c in chosen["candidates"]} == {0, 1}
    # 4. evaluate the run's export and the committed base expert on the test episodes into their default folders,
    #    then compare them paired with the page's own command (so the page's compare reads what its evals write)
    monkeypatch.chdir(tmp_path)
    for policy in (run / "exported" / "policy.pt2", REPO / "docs" / "policies" / "base_actor.pt"):
        eval_main(["--policy", str(policy), "--scenario", "simple", "--episodes", "2", "--episode-length-s", "0.4",
                   *TINY])
    assert default_out(run / "exported" / "policy.pt2") == Path("results/eval/base") / run.name / "policy"
    (compare_line,) = [line.split("compare", 1)[1].split() for line in (REPO / "docs" / "workflow.md").read_text()
                       .splitlines() if "python -m dls_quadruped.eval.compare" in line and "<run>" in line]
    files = [arg.replace("<run>", run.name) for arg in compare_line]
    for f in files:
        result = json.loads(Path(f).read_text())
        assert result["split"] == "test" and result["episodes"] == 2
    rows = compare_main([*files, "--out", str(tmp_path / "diff.json")])
    assert (tmp_path / "diff.json").is_file() and any(r.get("episodes") == 2 for r in rows), rows


def test_two_runs_evaluations_never_share_a_folder(tmp_path):
    """`make eval POLICY=runs/<task>/<run>/exported/policy.pt2` of two runs: two folders named after the runs;
    a committed policy's folder is its file's stem, as the workflow page's compare example reads it."""
    outs = set()
    for name in ("2026-11-27_10-00-00", "2026-11-28_10-00-00"):
        run = tmp_path / "runs" / "base" / name
        (run / "exported").mkdir(parents=True)
        (run / "task.yaml").write_text("name: base\n")
        outs |= {default_out(run / "exported" / "policy.pt2"), default_out(run / "model_450.pt")}
    assert outs == {Path("results/eval/base") / n / s for n in ("2026-11-27_10-00-00", "2026-11-28_10-00-00")
                    for s in ("policy", "model_450")}
    assert default_out(Path("docs/policies/base_actor.pt")) == Path("results/eval/base_actor")
    assert default_out(tmp_path / "elsewhere" / "policy.pt2") == Path("results/eval/policy")
