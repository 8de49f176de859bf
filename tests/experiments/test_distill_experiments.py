"""The distillation experiment scripts run end to end on a tiny scale and write their tables.

The tiny task ends episodes after 1 s; one run per script (``--only``), two epochs, two seeds of
2 robots each.
"""

from __future__ import annotations

import csv
import json
import sys

import pytest
import yaml

from dls_quadruped.envs.config import TASKS_DIR
from experiments import (
    distill_common,
    distill_eval,
    fig24_selector,
    table11_naive_vs_dagger,
    table11_sweep,
    table12_batch_size,
    table13_encodings,
)

TINY_SCALE = {"seeds": 2, "train": {"epochs": 2, "datapoints_per_epoch": 30, "dataset_cap": 1000},
              "collect": {"num_envs": 2}, "evaluate": {"test_datapoints": 10, "test_episodes": 2, "sp_episodes": 2}}


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    task = tmp_path / "tiny.yaml"
    task.write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), "env": {"episode_length_s": 1.0},
                                    "scene": {"num_workers": 0}}))
    for module in (distill_common, distill_eval):  # training and evaluation envs
        monkeypatch.setattr(module, "TASK", str(task))
    monkeypatch.setitem(distill_common.SCALES, "small", TINY_SCALE)
    return tmp_path


def read_csv(path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def run_script(monkeypatch, module, out, only):
    monkeypatch.setattr(sys, "argv", [module.__file__, "--scale", "small", "--out", str(out), "--only", only])
    module.main()


def test_table11_writes_our_numbers_beside_the_thesis(tiny, monkeypatch):
    out = tiny / "t11"
    run_script(monkeypatch, table11_naive_vs_dagger, out, "naive_first-spline")
    rows = read_csv(out / "table.csv")
    assert len(rows) == 1 and rows[0]["Algorithm"] == "naive" and rows[0]["thesis SP"] == "55.62 %"
    assert rows[0]["SP episodes"] == "2" and rows[0]["train datapoints"] == "60"  # naive: 2 epochs x 30 at once
    assert rows[0]["seeds"] == "2" and len(rows[0]["SP per seed [%]"].split(" / ")) == 2
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["runs"]["naive_first-spline"]["resolved"]["algorithm"] == "naive"
    assert (out / "table11.png").stat().st_size > 0 and "Table 11" in (out / "table.md").read_text()
    assert not list((out / "runs" / "naive_first-spline").glob("seed_*"))  # datasets are not kept by default
    # a finished run is not trained again
    mtime = (out / "runs" / "naive_first-spline" / "result.pt").stat().st_mtime
    run_script(monkeypatch, table11_naive_vs_dagger, out, "naive_first-spline")
    assert (out / "runs" / "naive_first-spline" / "result.pt").stat().st_mtime == mtime


@pytest.mark.slow
def test_table11_naive_variant_trains_on_the_naive_runs_data(tiny, monkeypatch):
    out = tiny / "t11v"
    run_script(monkeypatch, table11_naive_vs_dagger, out, "naive-dagger-steps_first-spline")  # + its source
    variant = {r["schedule"]: r for r in read_csv(out / "table.csv")}["DAgger's steps"]
    assert variant["train datapoints"] == "60" and variant["gradient steps"] == str(1 + 1)  # ceil(30/64) + ceil(60/64)
    assert json.loads((out / "config.json").read_text())["runs"]["naive-dagger-steps_first-spline"]["data_from"] \
        == "naive_first-spline"


@pytest.mark.slow
def test_fig24_has_sp_for_every_epoch(tiny, monkeypatch):
    out = tiny / "f24"
    run_script(monkeypatch, fig24_selector, out, "indicator")
    rows = read_csv(out / "table.csv")
    assert [r["epoch"] for r in rows] == ["1", "2"] and [r["beta"] for r in rows] == ["1", "0"]
    assert (out / "fig24.png").is_file()


def test_train_only_trains_and_stops_before_the_table(tiny, monkeypatch):
    """--train-only (a long script split over processes): the run is finished (result.pt, no partial
    .tmp left), no evaluation or table is written, and the exit status is 0."""
    out = tiny / "t11_train_only"
    monkeypatch.setattr(sys, "argv", [table11_naive_vs_dagger.__file__, "--scale", "small", "--out", str(out),
                                      "--only", "naive_first-spline", "--train-only"])
    with pytest.raises(SystemExit) as stop:
        table11_naive_vs_dagger.main()
    assert stop.value.code == 0
    run = out / "runs" / "naive_first-spline"
    assert (run / "result.pt").is_file() and not (run / "result.pt.tmp").exists()
    assert not (out / "table.csv").exists() and not (out / "results.json").exists()


@pytest.mark.slow
def test_table12_and_table13_rows(tiny, monkeypatch):
    run_script(monkeypatch, table12_batch_size, tiny / "t12", "batch_512")
    row = read_csv(tiny / "t12" / "table.csv")[0]
    assert row["batch"] == "512" and row["gradient steps"] == "2"  # 30 then 60 rows: one step per pass
    monkeypatch.setattr(sys, "argv", [table13_encodings.__file__, "--scale", "small", "--out", str(tiny / "t13"),
                                      "--only", "10_spline-spline_dt0.02_H10", "12_first-spline_dt0.02_H10",
                                      "16_spline-spline_dt0.02_H15"])
    table13_encodings.main()
    rows = read_csv(tiny / "t13" / "table.csv")
    assert [(r["N°"], r["Dim."], r["thesis SP"]) for r in rows] == [("10", "88", "97.43"), ("12", "64", "98.7"),
                                                                      ("16", "88", "95.6")]
    # rows 10 and 16 once printed one MSE: the same test states, but each row's own labels and students
    assert rows[0]["MSE per seed"] != rows[2]["MSE per seed"]
    assert rows[0]["test windows"] == rows[2]["test windows"] == "10"
    metrics = json.loads((tiny / "t13" / "runs" / "12_first-spline_dt0.02_H10" / "metrics.json").read_text())
    assert metrics["trained_with"] == ["10_spline-spline_dt0.02_H10", "12_first-spline_dt0.02_H10"]  # one group
    assert len(table13_encodings.runs()) == 36
    assert [r.row["Dim."] for r in table13_encodings.runs()][:6] == [108, 96, 100, 88, 76, 64]


def test_table11_sweep_grid_is_the_plans():
    """The grid written in docs/experiments/distillation.md before the first run: 4 sizes x 2 collections x
    {naive, DAgger}, 10 epochs of a tenth of the data, first-spline H = 5 dt = 0.02 s, batch 64; only the narrow
    collection overrides the task (one command per episode of 15 s)."""
    runs = table11_sweep.runs(table11_sweep.SIZES)
    assert len(runs) == 16 and len({r.name for r in runs}) == 16
    r = next(r for r in runs if r.name == "naive_narrow_400k")
    assert r.overrides["train"] == {"batch_size": 64, "epochs": 10, "datapoints_per_epoch": 40_000}
    assert r.overrides["encoding"] == {"p": "first", "F": "spline", "horizon": 5, "dt": 0.02}
    assert r.collect["commands"]["base_velocity"]["resampling_time_s"][0] > 15.0
    assert all(x.collect is None for x in runs if x.row["collection"] == "today")
    assert table11_sweep.EVALUATIONS["disturbed"]["observations"]["policy"]["noise_scale"] == 1.0


@pytest.mark.slow  # ~10 s: two tiny distillations and two evaluations
def test_table11_sweep_pairs_naive_with_dagger_under_each_collection_and_evaluation(tiny, monkeypatch):
    """The narrow collection's env and the disturbed evaluation's env get their task overrides (and only those);
    each naive row carries naive - DAgger for both evaluations."""
    seen = []
    real = distill_common.distill_task

    def spy(task, num_workers, overrides=None):
        seen.append(overrides)
        return real(task, num_workers, overrides)

    monkeypatch.setattr(distill_common, "distill_task", spy)  # the collection env
    monkeypatch.setattr(distill_eval, "distill_task", spy)  # the evaluation envs
    monkeypatch.setattr(table11_sweep, "SIZES", (60,))
    monkeypatch.setattr(table11_sweep, "EPOCHS", 2)
    out = tiny / "t11s"
    monkeypatch.setattr(sys, "argv", [table11_sweep.__file__, "--scale", "small", "--out", str(out), "--sizes", "60",
                                      "--only", "naive_narrow_60", "dagger_narrow_60"])
    table11_sweep.main()
    narrow, disturbed = table11_sweep.COLLECTIONS["narrow"], table11_sweep.EVALUATIONS["disturbed"]
    assert seen == [narrow, None, disturbed]  # one narrow collection env (both runs), then the two evaluations
    cfg = real(str(distill_common.TASK), None, narrow)
    assert cfg.data["commands"]["base_velocity"]["resampling_time_s"] == [1000.0, 1000.0]
    rows = read_csv(out / "table.csv")
    assert [(r["collection"], r["algorithm"], r["datapoints"]) for r in rows] == [("narrow", "naive", "60"),
                                                                                 ("narrow", "dagger", "60")]
    assert rows[0]["SP naive - DAgger, plain"].endswith("]") and rows[0]["SP naive - DAgger, disturbed"].endswith("]")
    assert rows[1]["SP naive - DAgger, plain"] == ""
    res = json.loads((out / "results.json").read_text())
    assert set(res["sp_difference_naive_minus_dagger"]) == {"naive_narrow_60 plain", "naive_narrow_60 disturbed"}
    assert json.loads((out / "config.json").read_text())["runs"]["dagger_narrow_60"]["resolved"]["train"][
        "datapoints_per_epoch"] == 30


@pytest.mark.parametrize("argv, code", [(["--help"], 0), (["--sizes", "7"], 2)])
def test_table11_sweep_help_and_a_bad_size(monkeypatch, capsys, argv, code):
    monkeypatch.setattr(sys, "argv", ["table11_sweep.py", *argv])
    with pytest.raises(SystemExit) as err:
        table11_sweep.main()
    assert err.value.code == code
    assert ("--sizes" in capsys.readouterr().out) if code == 0 else ("invalid choice: 7" in capsys.readouterr().err)
