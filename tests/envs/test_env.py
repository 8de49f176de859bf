"""The env end to end: every task builds and steps, bookkeeping of resets/time-outs, events, curriculum."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.mdp import curriculum as cur_mdp
from dls_quadruped.envs.mdp import events as ev_mdp
from dls_quadruped.robots.aliengo import constants as C

OBS_DIM = 3 + 3 + 3 + 12 + 12 + 28 + 4 + 4 + 187 + 3  # Table 2 + velocity command
SMALL = {"scene": {"num_workers": 0},
         "terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}


def make_env(name: str, num_envs: int = 4, **extra) -> LocomotionEnv:
    overrides = {**SMALL, **extra}
    return LocomotionEnv(load_task(name, overrides=overrides), num_envs=num_envs, verbose=False)


@pytest.mark.parametrize("name", ["base", "rough", "speed", "climb"])
def test_task_steps_with_random_actions(name):
    env = make_env(name)
    try:
        obs = env.get_observations()
        assert obs["policy"].shape == (4, OBS_DIM)
        for _ in range(50):
            obs, rew, dones, extras = env.step(torch.randn(4, 28))
            assert obs["policy"].shape == (4, OBS_DIM) and torch.isfinite(obs["policy"]).all()
            assert rew.shape == (4,) and torch.isfinite(rew).all()
            assert dones.shape == (4,) and extras["time_outs"].shape == (4,)
    finally:
        env.close()


def test_time_out_bookkeeping():
    env = make_env("base", env={"episode_length_s": 0.2})  # 10 policy steps
    try:
        assert env.max_episode_length == 10
        for k in range(1, 11):
            _, _, dones, extras = env.step(torch.zeros(4, 28))
            if k < 10:
                assert not extras["time_outs"].any() and int(env.episode_length_buf[0]) == k
        failed = env.termination_manager.terminated
        assert torch.equal(extras["time_outs"], ~failed) and dones.bool().all()
        assert (env.episode_length_buf == 0).all()
        log = env.episode_log.read()  # the steps' episode values, summed on the device, read once
        assert extras["log"] == {} and "Episode_Reward/track_lin_vel_xy" in log
        assert log["Episode_Termination/time_out"] == float((~failed).sum())  # the one step with resets
        assert env.episode_log.read() == {}  # read restarts the sums
    finally:
        env.close()


def test_events_touch_only_targeted_envs():
    env = make_env("rough")
    try:
        captured = {}
        env.scene.sim.set_model_field = lambda name, ids, values, index=None: captured.__setitem__(
            name, (ids, values, index))
        mask = torch.tensor([False, True, False, True])  # terms act on masks; the backend keeps the masked rows
        ev_mdp.randomize_friction(env, mask, friction_range=(0.4, 0.8))
        got_mask, values, index = captured["geom_friction"]
        geoms = env.scene.friction_geom_ids
        assert got_mask is mask and list(index) == geoms and values.shape == (4, 4, 3)
        assert [env.scene.model.geom(g).name for g in geoms] == list(C.FOOT_GEOM_NAMES)
        assert ((values[..., 0] >= 0.4) & (values[..., 0] <= 0.8)).all()
        assert (values[..., 1:] == env.scene.model.geom_friction[geoms, 1:]).all()  # torsional, rolling kept
        ev_mdp.randomize_base_mass(env, mask, scale_range=(0.85, 1.15))
        _, mass, _ = captured["body_mass"]
        # Table 3: +-15 % of the whole robot's mass (24.64 kg), carried by the trunk, not +-15 % of the trunk
        ratio = mass.sum(axis=1) / env.scene.model.body_mass.sum()
        assert ((ratio >= 0.85) & (ratio <= 1.15)).all() and (mass[:, 2:] == env.scene.model.body_mass[2:]).all()
        added = mass[:, 1] - env.scene.model.body_mass[1]
        np.testing.assert_allclose(added, (ratio - 1.0) * C.TOTAL_MASS, rtol=1e-9)
        # push: only envs 0 and 2 change velocity, by at most 0.5 m/s per axis
        before = env.state.base_lin_vel_w.clone()
        ev_mdp.push_robot(env, torch.tensor([True, False, True, False]), velocity_range=(-0.5, 0.5))
        env.refresh_state()
        after = env.state.base_lin_vel_w
        assert torch.equal(after[[1, 3]], before[[1, 3]])
        d = (after[[0, 2], :2] - before[[0, 2], :2]).abs()
        assert (d <= 0.5 + 1e-5).all() and (d > 0).any()
        w0 = env.scene.sim.buf.command["wrench_w"].clone()
        ev_mdp.external_wrench(env, torch.tensor([False, False, True, False]), force_range=(-10, 10),
                               torque_range=(-1, 1))
        w = env.scene.sim.buf.command["wrench_w"]
        assert torch.equal(w[[0, 1, 3]], w0[[0, 1, 3]]) and (w[2, :3].abs() <= 10).all() and (w[2, 3:].abs() <= 1).all()
        assert not torch.equal(w[2], w0[2])
    finally:
        env.close()


def test_terrain_curriculum_moves_levels_up_and_down():
    env = make_env("rough")
    try:
        scene = env.scene
        scene.update_levels(torch.arange(4), 1 - scene.terrain_levels)  # everyone on row 1
        state = env.state.clone()
        origins = scene.env_origins
        state.base_pos_w[:, :2] = origins[:, :2]
        state.base_pos_w[0, 0] += 0.6 * scene.terrain.cfg.tile_size  # walked far: up
        env._state = state
        env.episode_length_buf[:] = 750
        env.termination_manager.time_outs[:] = True  # every episode ran to its end
        env.command_manager.commanded_disp[:] = torch.tensor([7.5, 0.0])  # asked for 7.5 m
        env.command_manager.commanded_disp[2] = 0.0  # env 2: asked to stand and stood: stays
        env.command_manager.commanded_disp[3, 0] = 0.15
        cur_mdp.terrain_levels(env, torch.tensor([True, True, True, False]))
        assert scene.terrain_levels[:3].tolist() == [2, 0, 1]
        assert int(scene.terrain_levels[3]) == 1  # not in the mask: untouched
        assert torch.equal(scene.env_origins[0], scene.tile_origins[2, scene.terrain_types[0]])
        # solving the last row sends the robot to a random row; never below 0
        scene.update_levels(torch.tensor([1]), torch.tensor([-1]))
        assert int(scene.terrain_levels[1]) == 0
    finally:
        env.close()


def _arc(v: torch.Tensor, omega: float, yaw0: float, t: float) -> torch.Tensor:
    """Closed form: world displacement after t of base velocity v = (v_x, v_y) at yaw rate omega
    from heading yaw0 (integral of R(yaw0 + omega s) v ds)."""
    a = omega * t
    local = torch.tensor([v[0] * np.sin(a) - v[1] * (1 - np.cos(a)), v[0] * (1 - np.cos(a)) + v[1] * np.sin(a)]) / omega
    c, s = np.cos(yaw0), np.sin(yaw0)
    return torch.tensor([c * local[0] - s * local[1], s * local[0] + c * local[1]])


def test_commanded_displacement_is_the_arc_of_the_command():
    env = make_env("rough", num_envs=2)
    try:
        cm = env.command_manager
        v = torch.tensor([0.6, -0.2])
        cm.command[:] = torch.tensor([[0.6, -0.2, 0.5], [0.6, -0.2, -0.8]])
        cm.commanded_disp[:] = 0.0
        cm.commanded_yaw[:] = torch.tensor([0.3, -2.0])
        for _ in range(750):  # 15 s at the 50 Hz policy rate
            cm.integrate(0.02)
        for i, (omega, yaw0) in enumerate([(0.5, 0.3), (-0.8, -2.0)]):
            np.testing.assert_allclose(cm.commanded_disp[i].numpy(), _arc(v, omega, yaw0, 15.0).numpy(), atol=2e-4)
        assert cm.commanded_yaw.tolist() == pytest.approx([0.3 + 7.5, -2.0 - 12.0], abs=1e-3)  # float32 sum
        # the env integrates it every step and restarts it, at the robot's heading, on reset
        env.reset()
        assert cm.commanded_disp.abs().max() == 0.0
        from dls_quadruped.core.rotations import yaw_from_quat
        assert torch.allclose(cm.commanded_yaw, yaw_from_quat(env.state.base_quat_w))
        cm.command[:] = torch.tensor([[0.5, 0.0, 0.0], [0.0, 0.3, 0.0]])
        cm.time_left[:] = 100.0  # no resampling
        env.step(torch.zeros(2, 28))
        assert torch.linalg.vector_norm(cm.commanded_disp, dim=-1).tolist() == pytest.approx([0.01, 0.006], rel=1e-5)
    finally:
        env.close()


def test_terrain_curriculum_keeps_a_perfect_tracker_on_an_arc_and_demotes_a_fall():
    """A robot at the end of the arc its command (0.8 m/s, 0.5 rad/s) asks for in 15 s stays on
    its row: the straight-line rule (|v| x 15 s / 2 = 6 m > the 1.83 m chord) demoted it. The same
    robot, had its episode ended by a fall, goes down."""
    env = make_env("rough")
    try:
        scene, cm = env.scene, env.command_manager
        scene.update_levels(torch.arange(4), 1 - scene.terrain_levels)
        chord = _arc(torch.tensor([0.8, 0.0]), 0.5, 0.0, 15.0)
        # not far enough to go up
        assert 1.8 < float(torch.linalg.vector_norm(chord)) < 0.5 * scene.terrain.cfg.tile_size
        cm.commanded_disp[:] = chord
        cm.command[:] = torch.tensor([0.8, 0.0, 0.5])  # what the straight-line rule read
        state = env.state.clone()
        state.base_pos_w[:, :2] = scene.env_origins[:, :2] + chord.to(state.base_pos_w)
        env._state = state
        env.episode_length_buf[:] = 750
        env.termination_manager.time_outs[:] = torch.tensor([True, False, True, True])
        cur_mdp.terrain_levels(env, torch.tensor([True, True, False, False]))
        assert scene.terrain_levels.tolist() == [1, 0, 1, 1]
    finally:
        env.close()


def test_penalties_switch_on_once_walking():
    env = make_env("base")
    try:
        rm = env.reward_manager
        assert rm.weights["action_rate"] == 0.0  # off until the robot walks
        ids = torch.ones(4, dtype=torch.bool)
        rm.episode_sums["track_lin_vel_xy"][:] = 0.2 * 1.5 * env.max_episode_length_s  # 20 % of max
        cur_mdp.penalties_when_walking(env, ids, ["action_rate"], "track_lin_vel_xy", 0.5)
        assert rm.weights["action_rate"] == 0.0
        rm.episode_sums["track_lin_vel_xy"][:] = 0.8 * 1.5 * env.max_episode_length_s
        cur_mdp.penalties_when_walking(env, ids, ["action_rate"], "track_lin_vel_xy", 0.5)
        assert rm.weights["action_rate"] == pytest.approx(-2.5e-5)
        # the switch reached the tensor the (compiled) compute reads, and the reward: step_reward = value * w * dt
        i = rm.weights.index["action_rate"]
        assert rm.weights.tensor[i].item() == pytest.approx(-2.5e-5)
        env.step(torch.ones(4, 28))
        expected = torch.nan_to_num(rm.terms[i](env).float()) * -2.5e-5 * env.step_dt
        assert torch.allclose(rm.step_reward[:, i], expected, rtol=1e-6) and (expected != 0).all()
    finally:
        env.close()


def test_reward_weights_mirror_into_the_device_tensor_and_name_unknown_terms():
    env = make_env("base", rewards={"track_lin_vel_xy": {"weight": 1.5, "params": {"sigma": 0.5}},
                                    "lin_vel_z": {"weight": 0.0}})
    try:
        rm = env.reward_manager
        i = rm.weights.index["lin_vel_z"]
        assert i not in rm.weights.active  # weight 0 at build: not computed
        compute = rm._compute
        env.step(torch.zeros(4, 28))
        assert (rm.step_reward[:, i] == 0).all()
        rm.weights.update({"lin_vel_z": -2.0})  # a write activates it and rebuilds the compute once
        assert i in rm.weights.active and rm._compute is not compute and rm.weights.tensor[i].item() == -2.0
        env.step(torch.ones(4, 28))
        expected = torch.nan_to_num(rm.terms[i](env).float()) * -2.0 * env.step_dt
        assert torch.allclose(rm.step_reward[:, i], expected, rtol=1e-6) and (expected != 0).any()
        with pytest.raises(KeyError, match="unknown reward term 'lin_vel_q'; allowed: "):
            rm.weights["lin_vel_q"] = 1.0
    finally:
        env.close()


def test_observation_noise_is_per_term_and_bounded():
    env = make_env("base", observations={"policy": {"noise_scale": 0.5}})
    try:
        om = env.observation_manager
        a, b = om.compute()["policy"], om.compute()["policy"]  # same state, two noise draws
        start = 0
        for term in om.groups["policy"]:
            dim = om.dims["policy"][term.name]
            d = (a[:, start:start + dim] - b[:, start:start + dim]).abs()
            bound = 2 * 0.5 * term.extra["noise"]
            if bound == 0:
                assert (d == 0).all(), term.name
            else:
                assert (d <= bound + 1e-5).all() and (d > 0).any(), term.name
            start += dim
        assert start == OBS_DIM
    finally:
        env.close()


def test_reward_is_weighted_sum_times_dt():
    env = make_env("base")
    try:
        _, rew, _, _ = env.step(torch.zeros(4, 28))
        rm = env.reward_manager
        for i, term in enumerate(rm.terms):
            expected = torch.nan_to_num(term(env).float()) * rm.weights[term.name] * env.step_dt
            assert torch.allclose(rm.step_reward[:, i], expected, atol=1e-6), term.name
        assert torch.allclose(rew, rm.step_reward.sum(dim=1), atol=1e-6)
        assert env.step_dt == pytest.approx(0.02)
    finally:
        env.close()


def test_speed_curriculum_widens_forward_range():
    env = make_env("speed")
    try:
        cm, rm = env.command_manager, env.reward_manager
        assert list(cm.params["lin_vel_x"]) == [0.0, 1.0]
        ids, mask = torch.arange(4), torch.ones(4, dtype=torch.bool)
        full = rm.weights["track_lin_vel_xy"] * env.max_episode_length_s
        rm.episode_sums["track_lin_vel_xy"][:] = 0.5 * full  # below the 0.7 threshold: no change
        assert float(cur_mdp.command_speed_growth(env, mask, "track_lin_vel_xy", 0.7, 0.1, 2.1)) == pytest.approx(1.0)
        assert float(cur_mdp.command_speed_growth(env, ~mask, "track_lin_vel_xy", 0.7, 0.1, 2.1)) == 1.0  # no env
        rm.episode_sums["track_lin_vel_xy"][:] = 0.9 * full
        for _ in range(15):
            top = cur_mdp.command_speed_growth(env, mask, "track_lin_vel_xy", 0.7, 0.1, 2.1)
        assert float(top) == pytest.approx(2.1)  # capped at the task's top speed
        # the curriculum wrote the device range the (compiled) samplers read; 500 draws from it: successive draws of
        # the 4 envs' schedules (each call advances their command stream)
        assert cm.range("lin_vel_x").tolist() == [0.0, pytest.approx(2.1)] and cm.params["lin_vel_x"] == [0.0, 1.0]
        cmd = torch.cat([env.command_manager.term.func(env, ids, **cm._sampler_params()) for _ in range(125)])
        assert cmd[:, 0].min() >= 0.0 and cmd[:, 0].max() <= 2.1 and cmd[:, 0].max() > 1.5
        # the host copy catches up when read back (a checkpoint); a later sync uploads nothing new
        assert env.command_manager.state_dict()["params"]["lin_vel_x"] == [0.0, pytest.approx(2.1)]
        cm.sync_ranges()
        assert cm._ranges["lin_vel_x"].tolist() == [0.0, pytest.approx(2.1)]
        # the same numbers from the tensor ranges as from the Python lists, on the same schedule state
        state = env.schedule.state_dict()
        from_lists = env.command_manager.term.func(env, ids, **cm.params)
        env.schedule.load_state_dict(state)
        assert torch.equal(env.command_manager.term.func(env, ids, **cm._sampler_params()), from_lists)
    finally:
        env.close()


def test_omnidirectional_command_stays_in_its_disc():
    env = make_env("base")
    try:
        ids = torch.arange(env.num_envs)
        cmd = torch.cat([env.command_manager.term.func(env, ids, max_speed=1.0, ang_vel_z=(-1.0, 1.0))
                         for _ in range(2000 // env.num_envs)])
        speed = cmd[:, :2].norm(dim=1)
        assert speed.max() <= 1.0 + 1e-6 and speed.max() > 0.95
        assert (cmd[:, 0] < -0.5).any() and (cmd[:, 1] > 0.5).any()  # all directions
    finally:
        env.close()


def test_balance_controller_through_the_env_action_path_stays_up():
    """End to end through the action manager: the balance controller's physical actions, normalised
    with the same stance count the action manager uses, keep 8 robots up for 2 s standing + 2 s
    trotting. Yaw is fixed at 0 because the balance controller applies its roll/pitch feedback about
    world axes (valid only near yaw 0)."""
    from dls_quadruped.control.balance import BalanceController
    from dls_quadruped.control.latent_action import normalise

    env = make_env("base", num_envs=8, events={"reset_robot": {"params": {"yaw": [0.0, 0.0]}}})
    try:
        ctrl = BalanceController()
        for stand in (True, False):
            for _ in range(100):
                s = env.state
                raw = normalise(ctrl(s, torch.zeros(8, 3), stand=stand), s.contact_cmd.sum(-1), env.action_manager.cfg)
                env.step(raw.float())
                assert not env.termination_manager.terminated.any()
        z = env.state.base_pos_w[:, 2]
        assert ((z > 0.30) & (z < 0.38)).all()
        # what the policy observes as its last action is the normalised, clipped action it sent
        assert torch.allclose(env.action_manager.applied_action + env.action_manager.violation,
                              env.action_manager.raw_action)
    finally:
        env.close()


def test_reset_placement_runs_before_other_reset_events(tmp_path):
    from dls_quadruped.envs.config import TASKS_DIR

    p = tmp_path / "t.yaml"
    p.write_text(f"inherit: {TASKS_DIR / 'base.yaml'}\nevents:\n  reset_robot: null\n"
                 "  wrench: {func: external_wrench, mode: reset,"
                 " params: {force_range: [5, 10], torque_range: [0, 0]}}\n"
                 "  place: {func: reset_robot, mode: reset}\n")
    task = load_task(p, overrides=SMALL)
    env = LocomotionEnv(task, num_envs=2, verbose=False)
    try:
        assert [t.name for t in env.event_manager.terms] == ["place", "wrench"]
        assert (env.scene.sim.buf.command["wrench_w"][:, :3] >= 5).all()  # not cleared by the placement
    finally:
        env.close()


def test_velocity_tracking_metric_is_the_episode_mean_planar_error():
    """Episode_Metric/lin_vel_xy_error = mean over the episode's steps of |v_xy,b - cmd_xy| (hand-accumulated)."""
    from dls_quadruped.envs.mdp import observations as obs_mdp

    env = make_env("base", env={"episode_length_s": 0.2})  # 10 policy steps
    try:
        by_hand = torch.zeros(4)
        for _ in range(9):
            env.step(torch.zeros(4, 28))
            by_hand += torch.linalg.vector_norm(obs_mdp.base_lin_vel(env)[:, :2] - env.command_manager.command[:, :2],
                                                dim=-1)
        torch.testing.assert_close(env._vel_err_sum, by_hand)
        _, _, dones, _ = env.step(torch.zeros(4, 28))
        assert dones.bool().all()
        metric = env.episode_log.read()["Episode_Metric/lin_vel_xy_error"]
        assert metric >= float(by_hand.mean()) / 10 - 1e-6  # the 10th step only adds a non-negative error
        assert metric <= float(by_hand.mean()) / 10 + 10.0 / 10  # and at most 10 m/s (a sanity bound) over 10 steps
        assert (env._vel_err_sum == 0).all()
    finally:
        env.close()
