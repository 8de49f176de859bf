"""The compiled env step of the Warp backends (``sim/warp_control.py``, the managers' computes) on Warp's CPU device.

Compiled (``scene.compile: true``) and eager runs of the same seeded base episodes with random actions, resets and
pushes agree (the same arithmetic, but fused float32 code rounds differently: 5.3e-5 m after 25 steps of falling
robots; each compiled function on one state to float32 round-off), the compiled step stays
within the budget of 300 torch operators per env step, and the schedule's compiled draws equal its eager ones bit
for bit.
Slow: compiling takes ~10-70 s on a 2-core machine (cached afterwards in torch's inductor cache).
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.envs.mdp.events import _placement
from dls_quadruped.envs.schedule import EpisodeSchedule

pytestmark = pytest.mark.slow

EVENTFUL = {"env": {"episode_length_s": 0.3},
            "events": {"push": {"func": "push_robot", "mode": "interval", "interval_s": [0.04, 0.1],
                                "params": {"velocity_range": [-0.5, 0.5]}}}}


def _run(compile: bool, steps: int = 25):
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    env = LocomotionEnv(load_task("base", overrides={**EVENTFUL, "scene": {"backend": "warp-cpu", "num_workers": 0,
                                                                             "compile": compile}}),
                        num_envs=4, seed=0, verbose=False)
    try:
        g = torch.Generator().manual_seed(0)
        rows, resets, logs = [], 0, {}
        for _ in range(steps):
            _, rew, done, _ = env.step(torch.randn(4, 28, generator=g))
            s = env.state
            rows.append(torch.cat([s.base_pos_w, s.joint_pos, s.joint_torque, s.foot_pos_w.flatten(1)], dim=1).double())
            resets += int(done.sum())
            for k, v in env.episode_log.read().items():  # the reset path's episode sums, counts and metrics
                logs.setdefault(k, []).append(float(v))
        reset_path = (env._reset_bookkeeping, env.fused(_placement), env.command_manager._compute,
                      env.command_manager._integrate, env.scene.sim.rate._reset)
        compiled = env.scene.sim.rate.compiled and all(f.compiled for f in reset_path)
        return torch.stack(rows), rew, resets, compiled, env.schedule.compile, logs
    finally:
        env.close()


def test_compiled_and_eager_physics_steps_agree():
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    eager, rew_e, resets_e, comp_e, sched_e, logs_e = _run(False)
    fused, rew_c, resets_c, comp_c, sched_c, logs_c = _run(True)
    assert (comp_e, sched_e, comp_c, sched_c) == (False, False, True, True)  # the reset path compiled too
    assert resets_e == resets_c > 4  # episodes of 15 steps, the same robots reset at the same steps
    # float32 round-off of the compiled action conversion, amplified over 25 steps of falling robots: 5.3e-5 measured
    assert torch.allclose(fused, eager, rtol=0, atol=1e-3), (fused - eager).abs().max()
    assert torch.allclose(rew_c, rew_e, rtol=1e-3, atol=1e-4)
    assert logs_c.keys() == logs_e.keys() and "Episode_Reward/track_lin_vel_xy" in logs_e
    for k, v in logs_e.items():  # what the compiled bookkeeping logged at each reset step, as the eager one did
        assert torch.allclose(torch.tensor(logs_c[k]), torch.tensor(v), rtol=1e-3, atol=1e-4), k


def test_each_compiled_compute_matches_its_eager_function_on_one_state():
    """On one state: the compiled action conversion, observations, rewards and terminations against the same
    functions run eagerly, to float32 round-off (the compiled code may fuse and reorder float32 arithmetic)."""
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    env = LocomotionEnv(load_task("base", overrides={**EVENTFUL, "scene": {"backend": "warp-cpu", "num_workers": 0,
                                                                             "compile": True}}),
                        num_envs=4, seed=0, verbose=False)
    try:
        g = torch.Generator().manual_seed(3)
        for _ in range(6):
            env.step(torch.randn(4, 28, generator=g))
        am, om, rm, tm = env.action_manager, env.observation_manager, env.reward_manager, env.termination_manager
        assert all(f.compiled for f in (am._convert, om._groups, rm._compute, tm._compute))
        am.raw_action[:] = torch.randn(4, 28, generator=g)
        refs = [am._convert(env.state), am._convert.fn(env.state)]
        for a, b in zip(*refs):
            assert torch.allclose(a, b, rtol=1e-6, atol=1e-6)
        obs = [om._groups(), om._groups.fn()]
        assert all(torch.allclose(obs[0][k], obs[1][k], rtol=1e-6, atol=1e-6) for k in obs[1])
        sums = {k: v.clone() for k, v in rm.episode_sums.items()}
        compiled = rm._compute(env.step_dt)
        for k, v in sums.items():
            rm.episode_sums[k].copy_(v)
        assert torch.allclose(compiled, rm._compute.fn(env.step_dt), rtol=1e-5, atol=1e-6)
        assert torch.equal(tm._compute(None), tm._compute.fn(None))
        # the reset placement of every robot: the same draws (schedule counters restored in between), the same poses
        draws = {k: v.clone() for k, v in env.schedule._draws.items()}
        args = (env, (0.8, 1.2), (-3.0, 3.0), 0.5, 0.4)
        placement = env.fused(_placement)
        placed = placement(*args)
        for k, v in draws.items():
            env.schedule._draws[k].copy_(v)
        for a, b in zip(placed, placement.fn(*args)):
            assert torch.allclose(a, b, rtol=1e-6, atol=1e-6)
        assert placement.compiled
    finally:
        env.close()


def test_compiled_step_launches_a_fraction_of_the_torch_operators():
    pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    from dls_quadruped.bench.gpu_probes import launches

    eager = launches("warp-cpu", torch.device("cpu"), 4, 12, compile=False)
    fused = launches("warp-cpu", torch.device("cpu"), 4, 12, compile=True)
    assert fused["compiled"] and not eager["compiled"]
    assert fused["warp_launches_per_step"] <= 150 and eager["warp_launches_per_step"] <= 150
    # a step with resets: MuJoCo Warp's reset_data and forward replayed from graphs (2 launches, ~125 launched), the
    # reset path's torch work compiled (the step with resets was 772 operators before); the seeded run resets robots
    # on 2 of the 12 counted steps
    assert fused["steps_with_resets"] >= 1 and fused["warp_launches_reset_step"] <= 20
    assert fused["torch_ops_reset_step"] <= 300 < eager["torch_ops_reset_step"]
    assert 0 < fused["torch_ops_in_compiled_graphs_per_step"] <= 40  # ~15 graph calls per env step, ~1 kernel each
    # the Warp path's budget for a base env step (docs/gpu.md)
    assert fused["torch_ops_per_step"] <= 300 < eager["torch_ops_per_step"]


def test_compiled_schedule_draws_equal_eager_ones():
    eager, fused = EpisodeSchedule(7, 32), EpisodeSchedule(7, 32, compile=True)
    ids = torch.arange(32)
    for s in (eager, fused):
        s.start_episodes(ids)
    g = torch.Generator().manual_seed(1)
    for k in range(12):
        sub = torch.randperm(32, generator=g)[: 1 + 2 * k]
        for stream in ("command", "push_robot"):
            assert torch.equal(eager.uniform(sub, (3,), -1.0, 2.0, stream=stream),
                               fused.uniform(sub, (3,), -1.0, 2.0, stream=stream))
            assert torch.equal(eager.integers(ids, 0, 7, stream=stream), fused.integers(ids, 0, 7, stream=stream))
        if k == 5:
            for s in (eager, fused):
                s.start_episodes(sub)


def test_another_seed_is_an_input_of_a_compiled_draw_not_a_recompile():
    """A compiled function that draws from the schedule (the reset path's do) reads the seed's hash as a tensor:
    ``env.reset(seed=...)`` with a new seed reuses the compiled graph, and the draws are the eager schedule's."""
    from torch._dynamo.utils import counters

    from dls_quadruped.core.compile import Fused

    fused, eager = EpisodeSchedule(7, 8, compile=True), EpisodeSchedule(7, 8)
    ids = torch.tensor([5, 1, 2])
    draw = Fused(lambda i: fused.uniform(i, (3,), -1.0, 2.0, stream="seeded"), True, "seeded draw", dynamic=True)
    for s in (fused, eager):
        s.start_episodes(torch.arange(8))
    for _ in range(3):  # eager first call, then traced
        assert torch.equal(draw(ids), eager.uniform(ids, (3,), -1.0, 2.0, stream="seeded"))
    graphs = counters["stats"]["unique_graphs"]
    for seed in (8, 123456):
        for s in (fused, eager):
            s.restart(seed)
            s.start_episodes(torch.arange(8))
        assert torch.equal(draw(ids), eager.uniform(ids, (3,), -1.0, 2.0, stream="seeded"))
    assert draw.compiled and counters["stats"]["unique_graphs"] == graphs
