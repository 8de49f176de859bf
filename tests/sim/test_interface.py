"""The simulator seam (``sim/interface.py``): the registry (``sim/registry.py``), and that everything above
``sim/`` -- the env's managers and MDP terms, checkpoints, the closed-loop MPC -- uses only the ``SimBackend``
protocol.

The strict backend below wraps the CPU backend and exposes nothing but the protocol, and copies every input it
receives (so no caller can rely on the backend aliasing its tensors) and every state it returns (so no caller can
rely on live CPU views); an env and a closed loop on it must give bit for bit what they give on ``cpu``.
"""

from __future__ import annotations

from dataclasses import fields

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.core.state import RobotState
from dls_quadruped.envs.config import ConfigError, load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import VecSim
from dls_quadruped.sim.interface import SimBackend, SimConfig
from dls_quadruped.sim.registry import (
    backend_names,
    make_backend,
    register_backend,
    unregister_backend,
)

SMALL = {"scene": {"num_workers": 0},
         "terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}


def _copy(x):
    if isinstance(x, torch.Tensor):
        return x.detach().clone()
    if isinstance(x, np.ndarray):
        return x.copy()
    return x


class StrictBackend:
    """The protocol and nothing else, over a ``VecSim``; inputs and returned states are copies."""

    def __init__(self, model: mujoco.MjModel, num_envs: int, cfg: SimConfig):
        self._inner = VecSim(model, num_envs, cfg)
        self.model = model
        self.num_envs = num_envs
        self.physics_dt = self._inner.physics_dt
        self.device = torch.device("cpu")
        self.calls: list[str] = []

    def _out(self, state: RobotState) -> RobotState:
        return state.clone()

    @property
    def state(self) -> RobotState:
        return self._out(self._inner.state)

    def total_weight(self) -> float:
        return self._inner.total_weight()

    def set_references(self, freq, duty, p_td_w, F_w) -> None:
        self.calls.append("set_references")
        self._inner.set_references(_copy(freq), _copy(duty), _copy(p_td_w), _copy(F_w))

    def step(self, num_physics_steps: int = 1) -> RobotState:
        self.calls.append("step")
        return self._out(self._inner.step(num_physics_steps))

    def reset(self, env_ids, base_pos_w, base_quat_w, joint_pos, joint_vel=None, base_lin_vel_w=None,
              base_ang_vel_b=None, phase=None) -> RobotState:
        self.calls.append("reset")
        return self._out(self._inner.reset(_copy(env_ids), _copy(base_pos_w), _copy(base_quat_w), _copy(joint_pos),
                                           _copy(joint_vel), _copy(base_lin_vel_w), _copy(base_ang_vel_b),
                                           _copy(phase)))

    def set_external_wrench(self, env_ids, force_w, torque_w) -> None:
        self.calls.append("set_external_wrench")
        self._inner.set_external_wrench(_copy(env_ids), _copy(force_w), _copy(torque_w))

    def set_base_velocity(self, env_ids, lin_vel_w) -> RobotState:
        self.calls.append("set_base_velocity")
        return self._out(self._inner.set_base_velocity(_copy(env_ids), _copy(lin_vel_w)))

    def set_model_field(self, name, env_ids, values, index=None) -> None:
        self.calls.append("set_model_field")
        self._inner.set_model_field(name, _copy(env_ids), _copy(values), index)

    def snapshot(self) -> dict:
        return self._inner.snapshot()

    def restore(self, snap: dict) -> RobotState:
        return self._out(self._inner.restore(snap))

    def close(self) -> None:
        self._inner.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@pytest.fixture
def strict_backend():
    made: list[StrictBackend] = []

    def factory(model, num_envs, cfg):
        made.append(StrictBackend(model, num_envs, cfg))
        return made[-1]

    register_backend("strict-test", factory, "the CPU backend behind the bare protocol (tests)")
    try:
        yield made
    finally:
        unregister_backend("strict-test")


def test_cpu_backend_is_registered_and_satisfies_the_protocol():
    assert backend_names()[0] == "cpu"
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    with make_backend("cpu", model, 2, SimConfig(num_workers=0)) as sim:
        assert isinstance(sim, VecSim) and isinstance(sim, SimBackend)
        assert sim.device == torch.device("cpu") and sim.state.base_pos_w.device == sim.device
        for f in fields(RobotState):
            assert getattr(sim.state, f.name).shape[0] == 2


def test_unknown_backend_is_one_line_naming_the_allowed_ones():
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    with pytest.raises(ValueError, match=r"unknown simulator backend 'warp-nope'; allowed: cpu \(") as err:
        make_backend("warp-nope", model, 2)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="already registered"):
        register_backend("cpu", lambda *a: None, "twice")


def test_task_file_names_an_unknown_backend():
    with pytest.raises(ConfigError, match=r"scene\.backend: unknown simulator backend 'cuda-typo'; allowed: \['cpu'"):
        LocomotionEnv(load_task("base", overrides={"scene": {"backend": "cuda-typo", "num_workers": 0}}),
                      num_envs=2, verbose=False)


def test_cpu_backend_takes_inputs_of_any_float_dtype_and_kind():
    """float32 tensors, float64 tensors and numpy arrays give the same step."""
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    outs = []
    for kind in ("f32", "f64", "numpy"):
        with make_backend("cpu", model, 2, SimConfig(num_workers=0)) as sim:
            w = sim.total_weight()
            refs = (torch.full((2, 4), 2.0), torch.full((2, 4), 0.6), torch.zeros(2, 4, 3),
                    torch.tensor([0.0, 0.0, w / 4]).expand(2, 4, 3))
            conv = {"f32": lambda t: t.float(), "f64": lambda t: t.double(), "numpy": lambda t: t.numpy()}[kind]
            sim.set_references(*(conv(t) for t in refs))
            outs.append(sim.step(4).base_pos_w.clone())
    assert torch.equal(outs[0], outs[1]) and torch.equal(outs[0], outs[2])


def _rollout(backend: str, task: str, steps: int = 12):
    env = LocomotionEnv(load_task(task, overrides={**SMALL, "scene": {"num_workers": 0, "backend": backend}}),
                        num_envs=4, seed=5, verbose=False)
    g = torch.Generator().manual_seed(1)
    out = []
    try:
        for _ in range(steps):
            obs, rew, dones, _ = env.step(torch.randn(4, 28, generator=g))
            out.append(torch.cat([obs["policy"].flatten(), rew, dones.float()]))
        saved = env.state_dict()
        after = [env.step(torch.randn(4, 28, generator=g))[0]["policy"] for _ in range(3)]
        env.load_state_dict(saved)
        again = [env.step(torch.randn(4, 28, generator=torch.Generator().manual_seed(2)))[0]["policy"]
                 for _ in range(1)]
        calls = set(env.scene.sim.calls) if backend != "cpu" else None
    finally:
        env.close()
    return torch.stack(out), after, again, calls


def test_env_on_the_bare_protocol_is_bit_identical(strict_backend):
    """The rough task (friction, mass, wrench, pushes, terrain) on the strict backend = on ``cpu``."""
    ref, ref_after, ref_again, _ = _rollout("cpu", "rough")
    got, after, again, calls = _rollout("strict-test", "rough")
    assert torch.equal(ref, got)
    assert all(torch.equal(a, b) for a, b in zip(ref_after, after))
    assert torch.equal(ref_again[0], again[0])
    # the rough task's events reached the backend through the protocol
    assert {"set_references", "step", "reset", "set_model_field", "set_external_wrench"} <= calls


def test_closed_loop_mpc_on_the_bare_protocol_is_bit_identical(strict_backend):
    """The naive-warm-start MPC acts through env.apply_action: same traces on the strict backend."""
    from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
    from dls_quadruped.closed_loop.loop import run_closed_loop
    from dls_quadruped.mpc.config import SamplerConfig

    traces = {}
    for backend in ("cpu", "strict-test"):
        task = load_task("base", overrides={"scene": {"num_workers": 0, "backend": backend}})
        env = LocomotionEnv(task, num_envs=2, seed=0, verbose=False)
        try:
            ctrl = make_controller(ControllerConfig("naive_warm_start", sampler=SamplerConfig(num_samples=200)), env)
            traces[backend] = run_closed_loop(env, ctrl, num_steps=6)
        finally:
            env.close()
    a, b = traces["cpu"], traces["strict-test"]
    for name in ("reward", "initial_cost", "rollout_cost", "qpos"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_apply_action_only_inside_step_controlled_and_for_exactly_one_policy_step():
    env = LocomotionEnv(load_task("base", overrides={"scene": {"num_workers": 0}}), num_envs=2, verbose=False)
    try:
        raw = torch.zeros(2, 28)
        with pytest.raises(RuntimeError, match="apply_action runs inside step_controlled"):
            env.apply_action(raw, 2)

        def plans(*steps):
            def physics():
                for j, k in enumerate(steps):
                    env.apply_action(raw, k, replan=j > 0)
            return physics

        with pytest.raises(RuntimeError, match=r"physics\(\) ran 2 physics steps through apply_action, a policy "
                                               r"step has 4"):
            env.step_controlled(plans(2))
        with pytest.raises(RuntimeError, match="exceed the policy step's 4"):
            env.step_controlled(plans(3, 3))
        with pytest.raises(ValueError, match="num_physics_steps must be an int >= 1"):
            env.step_controlled(plans(0))
        env.step_controlled(plans(1, 3))  # any split that adds up to the policy step
    finally:
        env.close()


def test_replan_keeps_the_policy_steps_previous_action():
    """Two plans in one policy step: the previous action is the one before the step, the action the last plan's."""
    env = LocomotionEnv(load_task("base", overrides={"scene": {"num_workers": 0}}), num_envs=2, verbose=False)
    try:
        g = torch.Generator().manual_seed(0)
        before, first, second = (0.3 * torch.randn(2, 28, generator=g) for _ in range(3))
        env.step(before)

        def physics():
            env.apply_action(first, 2)
            env.apply_action(second, 2, replan=True)

        env.step_controlled(physics)
        am = env.action_manager
        assert torch.equal(am.prev_raw_action, before) and torch.equal(am.raw_action, second)
    finally:
        env.close()
