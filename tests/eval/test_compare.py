"""eval.compare: paired differences of two evaluations, derived by hand; episodes that are not the same are refused."""

from __future__ import annotations

import json

import pytest

from dls_quadruped.cli import UserError
from dls_quadruped.eval.compare import compare, main

CMD = [[0.5, 0.0, 0.0], [0.4, 0.1, 0.0], [0.3, -0.1, 0.2], [0.6, 0.0, -0.2]]


def result(policy: str, fell: list[bool], reward: list[float | None], **over) -> dict:
    return {"scenario": "simple", "seed": 0, "episodes": 4, "episode_length_s": 15.0, "policy": policy,
            "per_episode": {"command": CMD, "fell": fell, "reward": reward, "length_s": [15.0, 7.5, 15.0, 3.0]}, **over}


def test_compare_by_hand():
    a = result("new.pt", [False, False, False, True], [2.1, 1.2, 2.0, 1.6])
    b = result("old.pt", [False, True, False, True], [2.0, 1.0, 2.0, 1.5])
    rows = {r["metric"]: r for r in compare(a, b)}
    rew = rows["mean reward per step"]
    assert rew["A - B"] == pytest.approx(0.1)  # (0.1 + 0.2 + 0 + 0.1) / 4
    assert rew["A"] == pytest.approx(6.9 / 4) and rew["B"] == pytest.approx(6.5 / 4)
    assert rew["relative"] == pytest.approx(0.4 / 6.5)
    assert rew["ci95"][0] <= 0.1 <= rew["ci95"][1] and rew["ci95"][0] >= 0.0  # every episode's difference is >= 0
    surv = rows["survival [share]"]
    assert surv["A - B"] == pytest.approx(0.25) and surv["episodes"] == 4  # one more survivor of four
    assert rows["episode length [s]"]["A - B"] == pytest.approx(0.0)  # same lengths recorded on both sides


def test_an_episode_without_a_value_is_left_out_of_both():
    a = result("new.pt", [False] * 4, [2.1, None, 2.0, 1.6])
    b = result("old.pt", [False] * 4, [2.0, 1.0, 2.0, 1.5])
    rew = {r["metric"]: r for r in compare(a, b)}["mean reward per step"]
    assert rew["episodes"] == 3 and rew["A - B"] == pytest.approx(0.2 / 3)
    assert rew["B"] == pytest.approx(5.5 / 3)  # B's mean over the same three episodes


def stairs_result(policy: str, climbed: list[float]) -> dict:
    return {"scenario": "stairs", "seed": 0, "episodes": 4, "episode_length_s": 15.0, "policy": policy,
            "steps_per_flight": 6, "per_episode": {"step_height": [0.05, 0.05, 0.1, 0.1], "command_v_x": [0.4] * 4,
                                                   "climbed_fraction": climbed, "fell": [False] * 4}}


def test_stairs_reached_the_top_and_climbed_fraction_by_hand():
    # flights of 6 x 5 cm and 6 x 10 cm: within 1 mm of the top counts as the top (0.9999 x 0.3 m is 0.03 mm short)
    a = stairs_result("new.pt", [1.0, 0.9999, 0.5, 1.0])
    b = stairs_result("old.pt", [1.0, 0.5, 0.2, 0.3])
    rows = {r["metric"]: r for r in compare(a, b)}
    top = rows["stairs: reached the top [share]"]
    assert top["A"] == pytest.approx(0.75) and top["B"] == pytest.approx(0.25) and top["A - B"] == pytest.approx(0.5)
    climbed = rows["stairs: climbed fraction"]
    assert climbed["A - B"] == pytest.approx((0.0 + 0.4999 + 0.3 + 0.7) / 4)
    assert rows["survival [share]"]["A - B"] == 0.0
    short = stairs_result("new.pt", [0.99, 1.0, 1.0, 1.0])  # 0.99 x 0.3 m is 3 mm short of the top: not reached
    assert {r["metric"]: r for r in compare(short, b)}["stairs: reached the top [share]"]["A"] == pytest.approx(0.75)


def test_speed_ratio_by_hand():
    """The speed sweep's selection metric: achieved / commanded forward speed per episode, 0 where the robot fell."""
    def speed_result(policy, achieved, fell):
        return {"scenario": "speed", "seed": 0, "episodes": 4, "episode_length_s": 15.0, "policy": policy,
                "per_episode": {"command_v_x": [0.5, 1.0, 2.0, 2.0], "achieved_v_x": achieved, "fell": fell,
                                "length_s": [15.0, 15.0, 15.0, 4.0]}}

    a = speed_result("new.pt", [0.5, 0.9, 1.5, None], [False, False, False, True])   # ratios 1, 0.9, 0.75, 0
    b = speed_result("old.pt", [0.45, 1.0, 1.0, 1.9], [False, False, False, False])  # 0.9, 1, 0.5, 0.95
    row = {r["metric"]: r for r in compare(a, b)}["speed: achieved / commanded v_x (0 if fell)"]
    assert row["A"] == pytest.approx(2.65 / 4) and row["B"] == pytest.approx(3.35 / 4)
    assert row["A - B"] == pytest.approx((0.1 - 0.1 + 0.25 - 0.95) / 4)


@pytest.mark.parametrize(("over", "named"), [({"seed": 1}, "seed"), ({"scenario": "forward"}, "scenario"),
                                             ({"episodes": 8}, "episodes")])
def test_other_episodes_are_refused_naming_what_differs(over, named):
    a = result("new.pt", [False] * 4, [2.0] * 4)
    with pytest.raises(UserError, match=named):
        compare(a, result("old.pt", [False] * 4, [2.0] * 4, **over))


def test_other_commands_are_refused():
    a = result("new.pt", [False] * 4, [2.0] * 4)
    b = result("old.pt", [False] * 4, [2.0] * 4)
    b["per_episode"]["command"] = CMD[::-1]
    with pytest.raises(UserError, match="commands differ"):
        compare(a, b)


def test_cli_writes_the_differences(tmp_path, capsys):
    pa, pb, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "d.json"
    pa.write_text(json.dumps(result("new.pt", [False] * 4, [2.1, 1.2, 2.0, 1.6])))
    pb.write_text(json.dumps(result("old.pt", [False] * 4, [2.0, 1.0, 2.0, 1.5])))
    rows = main([str(pa), str(pb), "--out", str(out)])
    saved = json.loads(out.read_text())
    assert saved["policy_a"] == "new.pt" and saved["policy_b"] == "old.pt" and len(saved["rows"]) == len(rows)
    assert "mean reward per step" in capsys.readouterr().out
    with pytest.raises(FileNotFoundError, match="missing.json"):
        main([str(tmp_path / "missing.json"), str(pb)])


def test_help_and_a_bad_flag():
    import subprocess
    import sys

    ok = subprocess.run([sys.executable, "-m", "dls_quadruped.eval.compare", "--help"], capture_output=True, text=True,
                        timeout=120, check=False)
    assert ok.returncode == 0 and "paired" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "dls_quadruped.eval.compare", "a.json", "b.json", "--bogus"],
                         capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and "--bogus" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def closed_loop(controllers: dict[str, dict], **settings) -> dict:
    return {"settings": {"scenario": "survival_sweep", "seed": 0, "episodes": 4, "seconds": 15.0,
                         "command": "simple task", "stairs_heights": None, **settings},
            "controllers": {name: {"per_episode": pe} for name, pe in controllers.items()}}


def test_closed_loop_controllers_of_two_runs_by_hand(tmp_path):
    """A warm start with 3 sampler seeds per episode (seeds averaged within an episode) against a policy run once,
    from two summary files of the same episodes."""
    mpc = {"survived": [[1, 0, 1, 0], [1, 1, 1, 0], [1, 0, 1, 0]], "rl_reward": [[2.0, 1.0, 2.2, None]] * 3}
    alone = {"survived": [[1, 0, 0, 0]], "rl_reward": [[1.9, 1.1, 2.0, 1.5]]}
    pa, pb = tmp_path / "pair.json", tmp_path / "single.json"
    pa.write_text(json.dumps(closed_loop({"rl_warm_start": mpc})))
    pb.write_text(json.dumps(closed_loop({"rl_warm_start": mpc, "rl_baseline": alone})))
    rows = {r["metric"]: r for r in main([str(pa), f"{pb}:rl_baseline"])}
    surv = rows["survival [share]"]
    # per episode: A = 1, 1/3, 1, 0; B = 1, 0, 0, 0 -> differences 0, 1/3, 1, 0
    assert surv["A - B"] == pytest.approx((1 / 3 + 1) / 4) and surv["episodes"] == 4
    assert surv["A"] == pytest.approx((1 + 1 / 3 + 1) / 4) and surv["B"] == pytest.approx(0.25)
    rew = rows["RL reward per step"]  # episode 3 has no value for A: left out of both
    assert rew["episodes"] == 3 and rew["A - B"] == pytest.approx((0.1 - 0.1 + 0.2) / 3)
    assert rew["ci95"][0] <= rew["A - B"] <= rew["ci95"][1]
    same = {r["metric"]: r for r in main([f"{pb}:rl_warm_start", str(pa)])}  # a controller against itself: 0
    assert same["survival [share]"]["A - B"] == 0.0  # its interval is not [0, 0]: seeds are resampled on each side
    assert same["RL reward per step"]["A - B"] == 0.0 and same["RL reward per step"]["ci95"] == [0.0, 0.0]


def test_closed_loop_runs_of_other_episodes_or_names_are_refused(tmp_path):
    pe = {"survived": [[1, 0, 1, 0]], "rl_reward": [[2.0, 1.0, 2.2, 1.0]]}
    one, two, other = tmp_path / "one.json", tmp_path / "two.json", tmp_path / "other.json"
    one.write_text(json.dumps(closed_loop({"rl_baseline": pe})))
    two.write_text(json.dumps(closed_loop({"rl_baseline": pe, "rl_warm_start": pe})))
    other.write_text(json.dumps(closed_loop({"rl_baseline": pe}, command="forward 1.5 m/s")))
    with pytest.raises(UserError, match="command"):
        main([str(one), str(other)])
    with pytest.raises(UserError, match="name one as"):  # two controllers: which one?
        main([str(one), str(two)])
    with pytest.raises(UserError, match="no controller 'student'.*rl_baseline, rl_warm_start"):
        main([str(one), f"{two}:student"])
    evaluation = tmp_path / "eval.json"
    evaluation.write_text(json.dumps(result("old.pt", [False] * 4, [2.0] * 4)))
    with pytest.raises(UserError, match="closed-loop result"):  # an eval result and a closed-loop controller
        main([str(one), str(evaluation)])
    with pytest.raises(UserError, match="not a closed-loop summary"):
        main([str(one), f"{evaluation}:rl_baseline"])


def experiment_run(folder, seed: int, cells: dict[str, dict], scenario: str = "survival") -> None:
    """An experiment script's output: results.json {cell: summary}, cells/<cell>.json, config.json with the seed."""
    (folder / "cells").mkdir(parents=True)
    out = {}
    for name, pe in cells.items():
        out[name] = {"cell": name, "controller": "rl_warm_start", "scenario": scenario, "episodes": 4, "seconds": 15.0,
                     "vx": None, "student": [f"{folder.name}.pt2"], "per_episode": pe}
        (folder / "cells" / f"{name}.json").write_text(json.dumps(out[name]))
    (folder / "results.json").write_text(json.dumps(out))
    (folder / "config.json").write_text(json.dumps({"seed": seed}))


def test_experiment_cells_of_two_runs_by_hand(tmp_path):
    """A table rerun with other policies is paired cell by cell with the committed run, from results.json:CELL or
    cells/CELL.json; a run of another seed is refused."""
    new = {"survived": [[1, 1, 1, 0]] * 3, "initial_cost": [[10.0, 20.0, 30.0, 40.0]] * 3}
    old = {"survived": [[0, 1, 0, 0]] * 3, "initial_cost": [[12.0, 20.0, 36.0, 40.0]] * 3}
    experiment_run(tmp_path / "new", 0, {"ws_base_survival": new})
    experiment_run(tmp_path / "old", 0, {"ws_base_survival": old})
    experiment_run(tmp_path / "seed1", 1, {"ws_base_survival": old})
    a = f"{tmp_path / 'new' / 'results.json'}:ws_base_survival"
    rows = {r["metric"]: r for r in main([a, str(tmp_path / "old" / "cells" / "ws_base_survival.json")])}
    assert rows["survival [share]"]["A - B"] == pytest.approx(2 / 4)          # episodes 0 and 2 survive only in A
    assert rows["initial cost"]["A - B"] == pytest.approx((-2 + 0 - 6 + 0) / 4)
    assert rows["initial cost"]["A"] == pytest.approx(25.0) and rows["initial cost"]["B"] == pytest.approx(27.0)
    with pytest.raises(UserError, match="seed 0 vs 1"):
        main([a, f"{tmp_path / 'seed1' / 'results.json'}:ws_base_survival"])
    # a cell written before cells recorded their scenario and length: the simple task, the run's --seconds
    experiment_run(tmp_path / "simple_new", 0, {"ws": new}, scenario="simple")
    (tmp_path / "old_run" / "cells").mkdir(parents=True)
    old_cell = {"cell": "ws", "controller": "rl_warm_start", "episodes": 4, "vx": None, "per_episode": old}
    (tmp_path / "old_run" / "results.json").write_text(json.dumps({"ws": old_cell}))
    (tmp_path / "old_run" / "config.json").write_text(json.dumps({"seed": 0, "seconds": 15.0}))
    rows = {r["metric"]: r for r in main([f"{tmp_path / 'simple_new' / 'results.json'}:ws",
                                          f"{tmp_path / 'old_run' / 'results.json'}:ws"])}
    assert rows["survival [share]"]["A - B"] == pytest.approx(2 / 4)
