"""The closed loop on the GPU code path (the ``warp-cpu`` backend, the ``warp`` kernel): no host read per MPC step.

``core/sync_probe.py`` counts the host reads and uploads of the whole closed loop (``run_closed_loop``: the
recorder, its probes, the controller's student queries, warm starts, solves and records, the env's steps with
their resets) for an MPC controller of 4 robots. Two runs of different lengths after a warm-up read back exactly
the same: the recorder's read-back when its loop ends (once per ``record``) and nothing per step; episodes of 10 env
steps end inside the runs (twice in the longer one), so the masked resets (``reset_where``) are counted too, and
every third solve records its step costs. On the ``cpu`` backend with the ``cpp`` kernel the same loop does read
per step (its kernel and its simulator are on the host by design): the control that the probe sees the loop.
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
from dls_quadruped.closed_loop.episodes import DEFAULT_STUDENT, commands, make_env
from dls_quadruped.closed_loop.loop import run_closed_loop
from dls_quadruped.core.sync_probe import sync_probe
from dls_quadruped.mpc.config import SamplerConfig

pytest.importorskip("warp")

WARP_BACKEND = {"dls_quadruped/sim/warp_backend.py:_check_overflow", "dls_quadruped/sim/warp_inputs.py:raise_flagged"}
"""The Warp backend's own reads, once every ``check_every`` (24) step calls (``tests/envs/test_host_sync.py``)."""
READ_BACK = {"dls_quadruped/envs/recorder.py:record", "dls_quadruped/envs/recorder.py:<dictcomp>"}
"""The recorder's read-back of its buffers when its loop ends (and its last step's look at the episodes' ends)."""


def _loop(name: str, backend: str, kernel: str):
    env = make_env(commands(4, 0, None), 0.2, 0, 0, backend=backend)  # episodes of 10 env steps
    cfg = ControllerConfig(name, student=DEFAULT_STUDENT, sampler=SamplerConfig(num_samples=128, kernel=kernel),
                           horizon_cost_every=3)
    return env, make_controller(cfg, env)


def _probed(env, controller, steps: int):
    with sync_probe() as report:
        traces = run_closed_loop(env, controller, num_steps=steps, stop_when_all_ended=False)
    return report, traces


@pytest.mark.parametrize("name", ["rl_warm_start", "naive_warm_start"])
def test_device_loop_reads_back_once_per_record(name):
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    env, controller = _loop(name, "warp-cpu", "warp")
    try:
        assert controller.device == torch.device("cpu") and controller.mpc.uses_device_solve(1)
        run_closed_loop(env, controller, num_steps=3)  # warm-up: buffers, constants, the solve's graph captured
        short, _ = _probed(env, controller, 4)
        first = controller._solves
        long, traces = _probed(env, controller, 14)  # 28 solves; every robot restarts after steps 3 and 13
    finally:
        env.close()
    assert set(short.outside(WARP_BACKEND)) and {s.key() for s in short.counts} - WARP_BACKEND <= READ_BACK
    assert short.outside(WARP_BACKEND) == long.outside(WARP_BACKEND), (short.by_site(), long.by_site())
    assert sum(n for s, n in long.counts.items() if s.key() in WARP_BACKEND) <= 4  # once per 24 step calls
    assert traces.mpc_fallbacks == 0 and traces.length.tolist() == [3] * 4  # 7 of the episode's 10 steps before
    solved = torch.from_numpy(traces.rollout_cost)  # (T, S, E), NaN after the episode's end
    assert solved.shape == (14, 2, 4) and solved[:3].isfinite().all() and solved[3:].isnan().all()
    recorded = torch.from_numpy(traces.step_costs[:3]).isfinite().all(dim=-1).all(dim=-1).flatten()  # solves
    assert recorded.tolist() == [(first + k) % 3 == 0 for k in range(6)]  # every 3rd solve
    if name == "rl_warm_start":
        assert traces.student_fallbacks == 0


def test_host_loop_reads_every_step():
    """The control: the ``cpp`` kernel on the ``cpu`` backend reads back per solve (the C++ kernel's inputs and the
    simulator's state go through the host), so the probe does see the loop's steps."""
    env, controller = _loop("naive_warm_start", "cpu", "cpp")
    try:
        run_closed_loop(env, controller, num_steps=2)
        short, _ = _probed(env, controller, 2)
        long, _ = _probed(env, controller, 6)
    finally:
        env.close()
    assert long.total > short.total
