"""The terrain-aware MPC in the closed loop (issue 27 item 6): ``ControllerConfig(ground="terrain")`` plans on
the env's terrain map (``env.scene.terrain.height_at``); the initial-cost probe uses the same ground; a bad
ground is a one-line error."""

from __future__ import annotations

import numpy as np
import pytest

from dls_quadruped.closed_loop.controllers import ControllerConfig
from dls_quadruped.closed_loop.episodes import commands, run_controllers
from dls_quadruped.closed_loop.loop import InitialCostProbe
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.inputs import GROUNDS, ground_inputs
from experiments.warm_start_common import Cell

E = 8


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_probe_and_mpc_share_the_terrain_ground() -> None:
    """The probe's initial cost at the start of each policy step is the state cost the MPC's first solve of that
    step computes at the same state (same references, same ground); on the survival terrain the terrain map
    and the blind stance-feet ground give different costs, so the map is what both used."""
    runs = {}
    for ground in ("terrain", "stance_feet"):
        cfg = ControllerConfig("naive_warm_start", sampler=SamplerConfig(num_samples=300), ground=ground)
        runs[ground] = run_controllers([cfg], commands(E, 0, None), 0.3, seed=0, num_workers=0,
                                       scenario="survival")["naive_warm_start"]
    for tr in runs.values():
        live = np.isfinite(tr.initial_cost)
        assert live.sum() > E
        np.testing.assert_allclose(tr.mpc_initial_cost[:, 0][live], tr.initial_cost[live], rtol=1e-4, atol=1e-3)
    first_t, first_s = runs["terrain"].initial_cost[0], runs["stance_feet"].initial_cost[0]  # same state at t = 0
    assert np.abs(first_t - first_s).max() > 1.0, (first_t, first_s)


def test_bad_ground_is_a_one_line_error() -> None:
    for make in (lambda: ControllerConfig("naive_warm_start", ground="map"),
                 lambda: InitialCostProbe(SamplerConfig(), ground="map"),
                 lambda: Cell("c", "naive_warm_start", ground="map")):
        with pytest.raises(ValueError, match=r"ground must be one of") as err:
            make()
        assert "\n" not in str(err.value) and "terrain" in str(err.value)
    with pytest.raises(ValueError, match="terrain map"):
        InitialCostProbe(SamplerConfig(), ground="terrain")
    with pytest.raises(ValueError, match="terrain map"):
        ground_inputs("terrain", None)
    assert GROUNDS == ("flat", "stance_feet", "terrain")


def test_cell_ground_defaults_to_the_scenarios() -> None:
    assert Cell("c", "naive_warm_start").plan_ground() == "flat"
    assert Cell("c", "naive_warm_start", scenario="survival").plan_ground() == "stance_feet"
    assert Cell("c", "naive_warm_start", scenario="survival", ground="terrain").plan_ground() == "terrain"


def test_terrain_ground_on_flat_ground_is_the_flat_ground() -> None:
    """The simple task's flat scene: planning on its terrain map is planning on z = 0, bit for bit."""
    traces = []
    for ground in ("flat", "terrain"):
        cfg = ControllerConfig("naive_warm_start", sampler=SamplerConfig(num_samples=300), ground=ground)
        traces.append(run_controllers([cfg], commands(2, 0, None), 0.3, seed=0, num_workers=0)["naive_warm_start"])
    for name in ("qpos", "rollout_cost", "initial_cost", "mpc_initial_cost", "reward"):
        np.testing.assert_array_equal(getattr(traces[1], name), getattr(traces[0], name), err_msg=name)
