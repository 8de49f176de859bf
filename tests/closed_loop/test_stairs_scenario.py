"""The eval suite's stairs in the closed loop (issue 27 item 6): every controller's robot e (each sampler
seed) stands on the row and tile the eval suite gives its env e, with the same command; success and the
climbed fraction of a trace are the eval suite's (``eval.stairs``); a wrong stairs option is a one-line error."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from dls_quadruped.closed_loop.__main__ import main
from dls_quadruped.closed_loop.controllers import ControllerConfig
from dls_quadruped.closed_loop.episodes import (
    STAIRS_HEIGHTS,
    commands,
    run_controllers,
    stairs_rows,
)
from dls_quadruped.closed_loop.loop import ClosedLoopTraces
from dls_quadruped.closed_loop.metrics import compare, stairs_episodes, summarize
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.eval import stairs as ST
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.eval.sweep import place_on_rows
from dls_quadruped.mpc.config import SamplerConfig

REPO = Path(__file__).resolve().parents[2]
HEIGHTS = (0.1, 0.2)
PER = 2  # episodes per height


def test_commands_and_rows_are_the_eval_suites() -> None:
    cmd = commands(PER, 3, None, "stairs", HEIGHTS)
    ref, group = ST.stairs_commands(HEIGHTS, PER, 3)
    np.testing.assert_array_equal(cmd, ref)
    np.testing.assert_array_equal(stairs_rows(len(cmd), len(HEIGHTS)), group)  # height-major
    assert commands(4, 0, None, "stairs").shape == (4 * len(STAIRS_HEIGHTS), 3)
    assert ((cmd[:, 0] >= 0.3) & (cmd[:, 0] <= 0.5)).all() and (cmd[:, 1:] == 0).all()
    with pytest.raises(ValueError, match="not a multiple of 2 heights"):
        stairs_rows(3, 2)


def test_every_controller_and_seed_plays_the_eval_suites_stairs_episode() -> None:
    """Paired: rl_baseline (1 robot per episode) and an MPC with 2 sampler seeds (robot s E + e) on the same
    row, tile, start and command as the eval suite's env e."""
    cmd = commands(PER, 0, None, "stairs", HEIGHTS)
    e = len(cmd)
    opts = EvalOptions(episodes=e, seed=0, num_workers=0, episode_length_s=0.1)
    ref = LocomotionEnv(ST.stairs_task(cmd, opts, HEIGHTS), num_envs=e, seed=0, verbose=False)
    try:
        place_on_rows(ref, stairs_rows(e, len(HEIGHTS)))
        ref_rows = ref.scene.terrain_levels.cpu().numpy()
        ref_origin = ref.scene.env_origins.cpu().numpy()
        ref_cmd = ref.command_manager.command.cpu().numpy()
    finally:
        ref.close()
    cfgs = [ControllerConfig("rl_baseline", policy=REPO / "docs/policies/base_actor.pt"),
            ControllerConfig("naive_warm_start", sampler=SamplerConfig(num_samples=100), ground="terrain")]
    traces = run_controllers(cfgs, cmd, 0.1, seed=0, num_workers=0, sampler_seeds=2, scenario="stairs", heights=HEIGHTS)
    assert [traces[c.name].replicas for c in cfgs] == [1, 2]
    for tr in traces.values():
        ep = np.arange(len(tr.command)) % e
        np.testing.assert_array_equal(tr.terrain["row"], ref_rows[ep])
        np.testing.assert_allclose(tr.terrain["origin_z"], ref_origin[ep, 2], atol=1e-6)
        np.testing.assert_allclose(tr.command, ref_cmd[ep], atol=1e-6)
        assert tr.terrain["stairs"] == {"heights": list(HEIGHTS), "steps": ST.steps_per_flight()}
        # on the platform of its row: 6 steps of h below the top
        np.testing.assert_allclose(tr.terrain["origin_z"], -6 * np.asarray(HEIGHTS)[ref_rows[ep]], atol=1e-6)
        assert np.isfinite(tr.ground_z[0]).all()
    np.testing.assert_array_equal(ref_rows, [0, 0, 1, 1])
    s = summarize(traces["naive_warm_start"], replicas=2)
    assert [r["step_height"] for r in s["stairs"]["per_height"]] == list(HEIGHTS)
    assert [r["robots"] for r in s["stairs"]["per_height"]] == [4, 4]
    assert "reached_top" in compare(s, summarize(traces["rl_baseline"]))


def _traces(ground_z: np.ndarray, rows: list[int], origin_z: list[float], fell: list[bool]) -> ClosedLoopTraces:
    t, e = ground_z.shape
    nan = np.full((t, e), np.nan, np.float32)
    solves = np.full((t, 1, e), np.nan, np.float32)
    return ClosedLoopTraces(
        controller="x", command=np.zeros((e, 3)), reward=np.ones((t, e)), initial_cost=nan,
        initial_cost_terms=np.full((t, e, 9), np.nan), vel_error=nan, power=nan, speed=nan,
        base_vel=np.zeros((t, e, 3)), rollout_cost=solves, rollout_input_cost=solves, mpc_initial_cost=solves,
        step_costs=np.full((t, 1, e, 10), np.nan), step_input_costs=np.full((t, 1, e, 10), np.nan),
        winner=np.full((t, 1, e), -1), fell=np.asarray(fell), length=np.full(e, t), qpos=np.zeros((t, 1, 19)),
        mpc_fallbacks=0, student_fallbacks=0, step_dt=0.5, ground_z=ground_z,
        terrain={"types": ["stairs_up"], "type": [0] * e, "row": rows, "rows": 2, "origin_z": origin_z,
                 "stairs": {"heights": [0.1, 0.2], "steps": 6}})


def test_success_and_climbed_fraction_by_hand() -> None:
    """Flights: row 0 = 6 x 10 cm from z = -0.6, row 1 = 6 x 20 cm from z = -1.2; NaN = after the episode."""
    nan = np.nan
    ground_z = np.array([
        # e0 (row 0): up 3 of 6 steps, then fell;  e1 (row 0): the top less 0.5 mm (within 1 mm: success)
        # e2 (row 1): top less 2 mm (not);          e3 (row 1): the top, then back down two steps
        [-0.6, -0.6, -1.2, -1.2],
        [-0.5, -0.3, -0.8, 0.0],
        [-0.3, -0.0005, -0.002, -0.4],
        [nan, -0.1, -0.5, nan],
    ])
    tr = _traces(ground_z, [0, 0, 1, 1], [-0.6, -0.6, -1.2, -1.2], [True, False, False, True])
    fraction, top = stairs_episodes(tr)
    np.testing.assert_allclose(fraction, [0.5, 0.5995 / 0.6, 1.198 / 1.2, 1.0], rtol=1e-9)
    np.testing.assert_array_equal(top, [False, True, False, True])
    s = summarize(tr)
    per = s["stairs"]["per_height"]
    assert [r["success"]["rate"] for r in per] == [0.5, 0.5]
    assert [r["survival"]["rate"] for r in per] == [0.5, 0.5]
    np.testing.assert_allclose([r["climbed_fraction"]["mean"] for r in per],
                               [(0.5 + 0.5995 / 0.6) / 2, (1.198 / 1.2 + 1.0) / 2])
    assert s["per_episode"]["reached_top"] == [[0.0, 1.0, 0.0, 1.0]]
    assert s["stairs"]["episode_row"] == [0, 0, 1, 1]


@pytest.mark.parametrize("argv, message", [
    (["--scenario", "stairs", "--vx", "0.5"], "argument --vx: the stairs scenario draws its own"),
    (["--scenario", "stairs", "--heights", "0.05,0.1,0.3"], "ascending and evenly spaced"),
    (["--scenario", "stairs", "--heights", "0.1,-0.1"], "argument --heights: step heights must be positive"),
    (["--scenario", "stairs", "--heights", "0.1,ten"], "argument --heights: expected comma-separated step heights"),
    (["--scenario", "survival", "--heights", "0.1,0.2"], "argument --heights: only for --scenario stairs"),
    (["--scenario", "stair"], "argument --scenario: invalid choice: 'stair'"),
])
def test_wrong_stairs_options_are_one_line_errors(argv, message, tmp_path: Path, capsys) -> None:
    from dls_quadruped.cli import run_cli

    with pytest.raises(SystemExit) as exc:
        run_cli(main, argv + ["--seconds", "0.1", "--out", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(re.escape(message), err[0]), err
