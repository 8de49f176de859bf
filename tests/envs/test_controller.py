"""The controller protocol's one env step (``envs/controller.py``) on a scripted env that logs its calls: a policy's
action goes through ``env.step``; a controller at its own rate sends ``decimation / physics_steps`` commands inside
``env.step_controlled``, raw actions through ``apply_action`` (``replan`` after the first) and references through
``apply_references``, each for ``physics_steps`` physics steps; bad rates and commands are refused."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.envs.controller import (
    EnvController,
    PolicyController,
    References,
    step,
)


class LoggingEnv:
    """Two robots, ``decimation`` physics steps per env step; logs ("step" | "apply_action" | "apply_references",
    ...) calls, and checks that step_controlled's physics ran exactly ``decimation`` physics steps."""

    num_envs, step_dt = 2, 0.02

    def __init__(self, decimation: int = 4):
        self.decimation = decimation
        self.calls: list[tuple] = []
        self._inside: int | None = None

    def get_observations(self) -> TensorDict:
        return TensorDict({"policy": torch.zeros(2, 3)}, batch_size=[2])

    def _out(self):
        return self.get_observations(), torch.zeros(2), torch.zeros(2, dtype=torch.long), {}

    def step(self, actions):
        self.calls.append(("step", actions))
        return self._out()

    def step_controlled(self, physics):
        self._inside = 0
        physics()
        assert self._inside == self.decimation, self._inside
        self._inside = None
        return self._out()

    def apply_action(self, raw, num_physics_steps, replan=False, finite=False):
        assert self._inside is not None
        self._inside += num_physics_steps
        self.calls.append(("apply_action", raw, num_physics_steps, replan))

    def apply_references(self, freq, duty, p_td_w, F_w, num_physics_steps):
        assert self._inside is not None
        self._inside += num_physics_steps
        self.calls.append(("apply_references", freq, num_physics_steps))


class Counting(EnvController):
    """Command j of an env step: a (2, 28) raw action filled with 10 * (env steps prepared) + j, or references
    whose frequency is that number."""

    def __init__(self, env, physics_steps, references=False):
        super().__init__(env, physics_steps)
        self.references, self.prepared, self.substeps = references, 0, []

    def prepare(self, obs):
        self.prepared += 1

    def act(self, obs, substep):
        self.substeps.append(substep)
        value = 10.0 * self.prepared + substep
        if self.references:
            return References(torch.full((2, 4), value), torch.full((2, 4), 0.5), torch.zeros(2, 4, 3),
                              torch.zeros(2, 4, 3))
        return torch.full((2, 28), value)


def test_a_policy_steps_the_env_with_its_action():
    env = LoggingEnv()
    ctrl = PolicyController(env, lambda obs: obs["policy"][:, :1] + 7.0)
    assert ctrl.commands_per_step == 1 and ctrl.rate_hz == pytest.approx(50.0)
    step(ctrl, env.get_observations())
    ctrl.step(env.get_observations())  # the method is the same step
    assert [c[0] for c in env.calls] == ["step", "step"]
    assert torch.equal(env.calls[0][1], torch.full((2, 1), 7.0))


@pytest.mark.parametrize("physics_steps, replans", [(1, [False, True, True, True]), (2, [False, True]),
                                                    (4, [False])])
def test_a_controller_at_its_own_rate_sends_every_command_inside_the_step(physics_steps, replans):
    env = LoggingEnv(decimation=4)
    ctrl = Counting(env, physics_steps)
    assert ctrl.commands_per_step == 4 // physics_steps and ctrl.rate_hz == pytest.approx(50.0 * 4 / physics_steps)
    for _ in range(2):
        step(ctrl, env.get_observations())
    n = 4 // physics_steps
    assert ctrl.substeps == list(range(n)) * 2
    assert [c[0] for c in env.calls] == ["apply_action"] * 2 * n
    assert [c[2] for c in env.calls] == [physics_steps] * 2 * n
    assert [c[3] for c in env.calls] == replans * 2
    assert [float(c[1][0, 0]) for c in env.calls] == [10.0 * k + j for k in (1, 2) for j in range(n)]
    assert ctrl.prepare_seconds >= 0.0 and ctrl.act_seconds > 0.0


def test_references_go_to_the_backend_at_any_rate():
    for physics_steps in (None, 2):
        env = LoggingEnv(decimation=4)
        step(Counting(env, physics_steps, references=True), env.get_observations())
        held = [4] if physics_steps is None else [2, 2]
        assert [(c[0], c[2]) for c in env.calls] == [("apply_references", h) for h in held]
        assert [float(c[1][0, 0]) for c in env.calls] == [10.0 + j for j in range(len(held))]


def test_bad_rates_and_commands_are_refused():
    env = LoggingEnv(decimation=4)
    for bad in (3, 0, -2, 2.0, True):
        with pytest.raises(ValueError, match=r"physics_steps must be an int >= 1 dividing the env step's 4"):
            Counting(env, bad)

    class Wrong(Counting):
        def act(self, obs, substep):
            return [0.0] * 28

    with pytest.raises(TypeError, match="raw action tensor or References, got list"):
        step(Wrong(env, 2), env.get_observations())
    with pytest.raises(TypeError, match="abstract"):
        EnvController(env)
