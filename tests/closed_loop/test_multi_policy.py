"""Several students warm-starting one MPC (issue 27 items 2, 7, 8): each student seeds its own sample
group with its share in one solve, two identical students equal one student with the summed share,
the winner's group switches are counted per second, and bad shares or students are one-line errors."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
from dls_quadruped.closed_loop.episodes import commands, make_env
from dls_quadruped.closed_loop.metrics import winner_switches_per_s
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.samples import group_layout

REPO = Path(__file__).resolve().parents[2]
STUDENT = REPO / "docs" / "policies" / "base_student_first_spline_h10.pt"
SMALL = SamplerConfig(num_samples=400)


def test_group_shares_take_the_naive_share_off_the_top() -> None:
    cfg = ControllerConfig("rl_warm_start", student=(STUDENT, STUDENT), sampler=SMALL, shares=(0.25, 0.75),
                           naive_share=0.2)
    assert cfg.students == (STUDENT, STUDENT)
    assert cfg.group_shares() == pytest.approx((0.2, 0.6, 0.2))
    assert ControllerConfig("rl_warm_start", student=(STUDENT,) * 4, sampler=SMALL).group_shares() == (0.25,) * 4
    assert ControllerConfig("rl_warm_start", student=STUDENT, sampler=SMALL).group_shares() == (1.0,)


@pytest.mark.parametrize("shares, match", [
    ((0.5, -0.5), "positive"), ((math.nan, 1.0), "positive"), ((0.3, 0.3), "sum to 1"), ((1.0,), "one per student"),
    ((0.0, 1.0), "positive"),
])
def test_bad_shares_are_refused(shares, match) -> None:
    with pytest.raises(ValueError, match=match):
        ControllerConfig("rl_warm_start", student=(STUDENT, STUDENT), sampler=SMALL, shares=shares)


def test_several_students_only_for_the_warm_start() -> None:
    with pytest.raises(ValueError, match="rl_warm_start only"):
        ControllerConfig("student", student=(STUDENT, STUDENT))


def _one_physics_step(students, shares=None):
    """One policy step (two solves) of 2 robots; the warm starts and shares every solve received."""
    env = make_env(commands(2, 0, None), 1.0, seed=0, num_workers=0)
    try:
        ctrl = make_controller(ControllerConfig("rl_warm_start", student=students, sampler=SMALL, shares=shares,
                                                seed=3), env)
        seen = []
        solve = ctrl.mpc.solve

        def spy(state, refs, ws, props, **kw):
            result = solve(state, refs, ws, props, **kw)
            seen.append(([w.clone() for w in ws], tuple(props), result))
            return result

        ctrl.mpc.solve = spy
        with torch.inference_mode():
            ctrl.step(env.get_observations())
        return seen, ctrl
    finally:
        env.close()


def test_two_students_seed_their_own_groups_with_their_shares() -> None:
    seen, ctrl = _one_physics_step((STUDENT, STUDENT), shares=(0.3, 0.7))
    assert len(seen) == 2  # two MPC solves per policy step
    ws, props, result = seen[0]
    assert props == pytest.approx((0.3, 0.7)) and len(ws) == 2
    torch.testing.assert_close(ws[0], ws[1])  # the same student twice: the same warm start
    _, _, counts = group_layout(SMALL.num_samples, props)
    assert counts == (120, 280)
    assert set(result.warm_start_index.tolist()) <= {0, 1}
    assert len(ctrl.step_records) == 2 and ctrl.step_records[0].warm_start_index.shape == (2,)


def test_two_identical_students_equal_one_with_the_summed_share() -> None:
    """Groups [0, M/2) and [M/2, M) around the same warm start draw the same samples as one group of M,
    except sample M/2, which is the warm start itself (a group's sample 0): so the solves agree
    whenever the one-student winner is not sample M/2 (checked, then required)."""
    two, _ = _one_physics_step((STUDENT, STUDENT), shares=(0.5, 0.5))
    one, _ = _one_physics_step(STUDENT)
    half = SMALL.num_samples // 2
    for (ws2, _, r2), (ws1, _, r1) in zip(two, one):
        torch.testing.assert_close(ws2[0], ws1[0])
        assert not (r1.best_index == half).any()
        torch.testing.assert_close(r2.best_index, r1.best_index)
        torch.testing.assert_close(r2.best_cost, r1.best_cost)
        torch.testing.assert_close(r2.F_h, r1.F_h)
        torch.testing.assert_close(r2.warm_start_index, (r1.best_index >= half).long())


def test_winner_switches_per_second_by_hand() -> None:
    # (T = 3 policy steps, S = 2 solves each, E = 2 robots) at a 0.02 s policy step: solves every 0.01 s
    w = np.array([[[0, 0], [1, 0]], [[1, 0], [0, -1]], [[0, -1], [0, -1]]], dtype=np.int16)
    out = winner_switches_per_s(w, 0.02)
    # robot 0: 0 1 1 0 0 0 -> 2 switches over 5 intervals of 0.01 s = 40 /s
    # robot 1: 0 0 0 (then no valid solve) -> 0 switches over 2 intervals
    np.testing.assert_allclose(out, [40.0, 0.0])
    assert np.isnan(winner_switches_per_s(np.array([[[0]], [[-1]]], dtype=np.int16), 0.02))[0]


def _cli(capsys, *args: str) -> subprocess.CompletedProcess:
    """The closed loop's command line, in this process (as ``python -m dls_quadruped.closed_loop``: ``run_cli``
    prints a user error as one line on stderr and exits 2; ``tests/test_entry_points.py`` checks that the
    interpreter-level entry point behaves the same)."""
    from dls_quadruped.cli import run_cli
    from dls_quadruped.closed_loop.__main__ import main

    capsys.readouterr()
    try:
        run_cli(main, list(args))
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    out = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out.out, out.err)


@pytest.mark.parametrize("args, words", [
    (("--controllers", "rl_warm_start", "--students", "base,nobody"), "'nobody' is neither a file"),
    (("--controllers", "rl_warm_start", "--students", "base,base", "--shares", "0.5,-0.5"), "positive"),
    (("--controllers", "rl_warm_start", "--students", "base,base", "--shares", "0.5,0.6"), "sum to 1"),
    (("--controllers", "rl_warm_start", "--shares", "1.0"), "--shares needs --students"),
    (("--controllers", "student", "--students", "base,base"), "rl_warm_start controller alone"),
    (("--controllers", "rl_warm_start", "--students", "base", "--encoding", "discrete-discrete"),
     "neither a file nor a committed student"),
])
def test_cli_refuses_bad_students_in_one_line(capsys, args, words) -> None:
    res = _cli(capsys, *args, "--episodes", "2", "--seconds", "0.1", "--samples", "100")
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in res.stderr


@pytest.mark.parametrize("flag, value, words", [
    ("--switching-cost", "-5", "SamplerConfig.switching_cost must be >= 0 and finite"),
    ("--switching-cost", "nan", "got nan"),
    ("--group-cost-smoothing", "1", "SamplerConfig.group_cost_smoothing must be in [0, 1)"),
])
def test_cli_refuses_bad_arbitration_in_one_line(capsys, flag, value, words) -> None:
    res = _cli(capsys, "--controllers", "rl_warm_start", "--students", "base,base", flag, value, "--episodes", "2",
               "--seconds", "0.1", "--samples", "100")
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and value in lines[0] and "Traceback" not in res.stderr


def test_switching_cost_steadies_the_winner_of_two_identical_students() -> None:
    """Two identical students: which group wins is a coin flip of the noise every solve (measured ~50 switches/s
    at M = 500); a switching cost of 1000 (above the noise's spread of the group bests, ~100 to 5000) keeps the
    first winner (measured 0 /s)."""
    from dls_quadruped.closed_loop.episodes import run_controllers

    cmds = commands(2, 0, None)
    rates = {}
    for s in (0.0, 1000.0):
        cfg = ControllerConfig("rl_warm_start", student=(STUDENT, STUDENT),
                               sampler=SamplerConfig(num_samples=500, switching_cost=s))
        traces = run_controllers([cfg], cmds, 1.0, seed=0, num_workers=0)["rl_warm_start"]
        rates[s] = winner_switches_per_s(traces.winner, traces.step_dt)
    assert (rates[0.0] > 10.0).all() and (rates[1000.0] < rates[0.0] / 5).all(), rates
