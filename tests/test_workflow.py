"""docs/workflow.md's train -> play -> choose -> evaluate -> compare steps, run for real at tiny sizes, each
step consuming what the one before wrote (the distillation and closed-loop steps at tiny sizes are
tests/learning/test_distill_cli.py::test_tiny_run_resume_and_outputs and
tests/closed_loop/test_closed_loop.py::test_cli_writes_summary; every command of the page is checked against
argparse and the Makefile by tests/test_docs_commands.py)."""

from __future__ import annotations

import json

from dls_quadruped.eval import select
from dls_quadruped.eval.__main__ import main as eval_main
from dls_quadruped.eval.compare import main as compare_main
from dls_quadruped.learning import play, train

TINY = ["--num-workers", "0"]


def test_train_play_select_evaluate_compare(tmp_path):
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
    # 4. evaluate it and the committed base expert on the test episodes, then compare them paired
    outs = []
    for policy, name in ((chosen["chosen"]["checkpoint"], "new"), ("docs/policies/base_actor.pt", "base_actor")):
        out = tmp_path / "eval" / name
        eval_main(["--policy", policy, "--scenario", "simple", "--episodes", "2", "--episode-length-s", "0.4",
                   "--out", str(out), *TINY])
        result = json.loads((out / "simple.json").read_text())
        assert result["split"] == "test" and result["episodes"] == 2
        outs.append(out / "simple.json")
    rows = compare_main([str(outs[0]), str(outs[1]), "--out", str(tmp_path / "diff.json")])
    assert (tmp_path / "diff.json").is_file() and any(r.get("episodes") == 2 for r in rows), rows
