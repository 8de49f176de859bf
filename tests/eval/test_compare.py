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
