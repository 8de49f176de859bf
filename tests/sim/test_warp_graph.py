"""sim/warp_graph.py: MuJoCo Warp's phases replayed from captured graphs give the same steps as launched ones.

Warp 1.19 records and replays graphs on its CPU device too, so this runs on ``warp-cpu`` (skipped without the
optional [gpu] extra, as in CI)."""

from __future__ import annotations

import mujoco
import pytest
import torch

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state

pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")

from dls_quadruped.sim import warp_graph
from dls_quadruped.sim.warp_backend import WarpSim


def _run(capture: bool, mass_change: bool = True, resets: bool = True) -> tuple[torch.Tensor, WarpSim]:
    """3 standing robots, 12 x 2 physics steps; robot 1 gets +8 kg trunk mass at step 4 (the first write of
    ``body_mass`` replaces MuJoCo Warp's shared array by a per-robot one), robot 2 a push at step 7 and another
    at step 10, robot 0 a reset to a perturbed home pose at step 5 and robots 0 and 2 at step 9 (the second reset
    and push replay captured graphs)."""
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    trunk = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    sim = WarpSim(model, 3, SimConfig(num_workers=0), device="cpu", capture=capture)
    out = []
    for k in range(12):
        if k == 4 and mass_change:
            mass = torch.as_tensor(model.body_mass).clone()[None]
            mass[0, trunk] += 8.0
            sim.set_model_field("body_mass", [1], mass)
        if k in (7, 10):
            sim.set_base_velocity([2], torch.tensor([[0.3, 0.1 * k - 0.8, 0.0]]))
        if k in (5, 9) and resets:
            ids = [0] if k == 5 else [0, 2]
            sim.reset(ids, **home_state(len(ids), seed=k, noise=0.1))
        s = sim.step(2)
        out.append(torch.cat([s.base_pos_w, s.base_quat_w, s.joint_pos, s.foot_force_w.flatten(1)], 1).clone())
    return torch.stack(out), sim


def test_captured_steps_are_bit_identical_to_launched_ones_across_a_field_change_and_a_push():
    launched, a = _run(capture=False)
    captured, b = _run(capture=True)
    assert a._step2.captures == 0 and b._step2.captures == 2  # captured, then again after body_mass was batched
    assert b.worlds.reset_data.captures == 1 and b.worlds.forward.captures == 1  # the second reset replayed
    assert torch.equal(captured, launched)
    assert not torch.equal(launched[5:, 0], _run(capture=False, resets=False)[0][5:, 0])  # the resets acted
    heavier = launched[-1, 1, 2] - launched[-1, 0, 2]
    assert heavier < -1e-4  # the extra mass sinks robot 1 (both paths saw it)


def test_a_reset_and_a_push_launch_one_graph_per_phase_once_captured(monkeypatch):
    """Once captured, a reset is two Warp launches (``reset_data`` of the masked worlds, ``forward``) and a push one
    (``step1``), where launched they are ~125 and ~60 kernel launches; a plain ``step(2)`` is four."""
    import mujoco_warp._src.warp_util  # noqa: F401  (MuJoCo Warp launches through the warp module)
    import warp as wp

    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    launches = []
    with WarpSim(model, 3, SimConfig(num_workers=0), device="cpu") as sim:
        for k in range(2):  # the first call of each phase runs directly, the second captures
            sim.reset([k], **home_state(1, seed=k, noise=0.05))
            sim.set_base_velocity([k], torch.tensor([[0.2, 0.0, 0.0]]))
            sim.step(2)
        for name in ("launch", "launch_tiled", "capture_launch"):
            original = getattr(wp, name)
            monkeypatch.setattr(wp, name, lambda *a, _f=original, _n=name, **k: (launches.append(_n), _f(*a, **k))[1])
        counts = []
        for call in (lambda: sim.reset([2, 0], **home_state(2, seed=5, noise=0.05)),
                     lambda: sim.set_base_velocity([1], torch.tensor([[0.0, 0.3, 0.0]])), lambda: sim.step(2)):
            launches.clear()
            call()
            counts.append(list(launches))
    assert counts == [["capture_launch"] * 2, ["capture_launch"], ["capture_launch"] * 4]
    uncaptured = WarpSim(model, 3, SimConfig(num_workers=0), device="cpu", capture=False)
    launches.clear()
    uncaptured.reset([2, 0], **home_state(2, seed=5, noise=0.05))
    assert len(launches) > 50 and "capture_launch" not in launches  # what the graphs replace
    uncaptured.close()


def test_without_invalidation_a_replaced_field_would_be_missed(monkeypatch):
    """The reason for ``StepGraph.invalidate``: a graph replays the old array's address, so with invalidation
    switched off the captured phases keep the shared (old) masses and robot 1's trajectory departs from the
    launched run's, while the other robots' do not."""
    monkeypatch.setattr(warp_graph.StepGraph, "invalidate", lambda self: None)
    stale, _ = _run(capture=True)
    launched, _ = _run(capture=False)
    assert torch.equal(stale[:4], launched[:4])  # identical until the field was replaced (before step 4)
    assert not torch.equal(stale[:, 1], launched[:, 1])
    assert torch.equal(stale[:, 0], launched[:, 0])


def test_capture_can_be_switched_off_and_on():
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    with WarpSim(model, 2, SimConfig(num_workers=0), device="cpu") as sim:
        assert sim.capture is True
        sim.step(3)
        sim.capture = False
        before = sim._step2.captures
        sim.step(3)
        assert sim.capture is False and sim._step2.captures == before


def test_non_finite_references_freeze_their_robot_and_are_raised_at_the_next_check():
    """set_references reads no value back: a NaN force makes robot 1 diverge (frozen, nothing non-finite
    published), and the deferred check names the reference; with check_every = 1 step() itself raises."""
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    with WarpSim(model, 3, SimConfig(num_workers=0), device="cpu") as sim:
        c = {k: v.clone() for k, v in sim.command.items()}
        c["F_w"][1] = float("nan")  # every foot: the stance feet turn it into NaN torques
        sim.set_references(c["freq"], c["duty"], c["p_td_w"], c["F_w"])
        state = sim.step(2)
        assert state.diverged.tolist() == [False, True, False]
        assert all(torch.isfinite(getattr(state, f)).all() for f in ("base_pos_w", "joint_torque", "foot_force_w"))
        with pytest.raises(ValueError, match=r"non-finite F_w"):
            sim.check_inputs()
        sim.check_inputs()  # reported once
        sim.check_every = 1
        sim.set_references(c["freq"], c["duty"] * float("inf"), c["p_td_w"], c["F_w"].nan_to_num())
        with pytest.raises(ValueError, match=r"non-finite duty"):
            sim.step(1)
    with pytest.raises(ValueError, match=r"p_td_w must have shape \(3, 4, 3\)"):
        WarpSim(model, 3, SimConfig(num_workers=0), device="cpu").set_references(
            c["freq"], c["duty"], c["p_td_w"][:, :2], c["F_w"])



def test_device_ids_out_of_range_are_clamped_and_raised_at_the_check_host_ids_at_once():
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    with WarpSim(model, 3, SimConfig(num_workers=0), device="cpu") as sim:
        before = sim.state.clone()
        sim.set_base_velocity(torch.tensor([5]), torch.tensor([[0.3, 0.0, 0.0]]))  # ids on the device: clamped to 2
        assert sim.state.base_lin_vel_w[2, 0] == pytest.approx(0.3) and sim.state.base_lin_vel_w[0, 0] == 0.0
        with pytest.raises(ValueError, match=r"env_ids out of \[0, 3\)"):
            sim.check_inputs()
        with pytest.raises(ValueError, match=r"env_ids must be in \[0, 3\), got min 0 max 7"):
            sim.set_base_velocity([0, 7], torch.zeros(2, 3))
        sim.set_external_wrench(torch.tensor([1]), torch.tensor([[float("nan"), 0.0, 0.0]]), torch.zeros(1, 3))
        with pytest.raises(ValueError, match=r"non-finite force_w"):
            sim.check_inputs()
        assert torch.equal(before.base_pos_w, sim.state.base_pos_w)
