"""One captured graph per env step (``envs/env_graph.py``, ``scene.cuda_graph``).

The CUDA graph itself needs a GPU; what it needs of the step is checked here. :class:`EmulatedCapture` does to the
Python-visible state what a replay does (reads at the capture's tensors, writes into the capture's outputs, no
Python), so an env stepped through it on ``warp-cpu`` gives the eager env's steps bit for bit only if the step keeps
its state in place. The first tests show the emulation on toy steps (a stale read it exposes, the Python numbers and
the replaced places it refuses), then :class:`EnvGraph`'s bookkeeping on a stand-in env, then the env itself.
"""

from __future__ import annotations

import contextlib
import dataclasses
import warnings
from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.envs.config import ConfigError, load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.env_graph import EmulatedCapture, EnvGraph, GraphMismatch


# ---------------------------------------------------------------------------------------------- the emulation
def _run(step, root: dict, calls: int, emulate: bool) -> list[float]:
    """``root["x"]`` after each of ``calls`` calls of ``step(root)``, eagerly or through the emulated graph."""
    if not emulate:
        out = []
        for _ in range(calls):
            step(root)
            out.append(float(root["x"].sum()))
        return out
    cap = EmulatedCapture(root)
    cap.capture(lambda _stream: step(root))
    out = [float(root["x"].sum())]
    for _ in range(calls - 1):
        cap.replay()
        out.append(float(root["x"].sum()))
    return out


def test_a_replaced_state_is_read_where_the_capture_read_it():
    """``x = x + 1`` each step: eagerly 1, 2, 3; replayed, the graph reads the tensor the capture read (still 0)
    and writes the one the capture made: 1, 1, 1 -- the bug a CUDA graph would have, shown on the CPU."""
    def step(root):
        root["x"] = root["x"] + 1

    assert _run(step, {"x": torch.zeros(())}, 3, emulate=False) == [1.0, 2.0, 3.0]
    assert _run(step, {"x": torch.zeros(())}, 3, emulate=True) == [1.0, 1.0, 1.0]


def test_in_place_state_and_replaced_outputs_replay_as_eagerly():
    """``x += 1`` in place, ``y = 2 x`` replaced but only written: the replay gives the eager values, and ``y`` is the
    capture's tensor every time (where a graph writes)."""
    def step(root):
        root["x"].add_(1)
        root["y"] = root["x"] * 2

    root = {"x": torch.zeros(2), "y": None}
    assert _run(step, {"x": torch.zeros(2), "y": None}, 4, emulate=False) == _run(step, root, 4, emulate=True)
    cap = EmulatedCapture(root)
    cap.capture(lambda _s: step(root))
    y = root["y"]
    cap.replay()
    assert root["y"] is y and torch.equal(y, torch.full((2,), 12.0))  # 4 + 1 + 1 = 6 steps of x, times 2


def test_python_numbers_changed_by_the_step_are_refused():
    def step(root):
        root["x"].add_(1)
        root["n"] += 1

    with pytest.raises(GraphMismatch, match=r"Python numbers \[\"env\['n'\]\"\]"):
        EmulatedCapture(root := {"x": torch.zeros(()), "n": 0}).capture(lambda _s: step(root))


def test_a_replay_that_replaces_other_places_than_the_capture_is_refused():
    """A step whose Python branches differ between calls (here on a counter outside the state): a graph replays
    the capture's branch only."""
    calls = {"n": 0}

    def step(root):
        calls["n"] += 1
        if calls["n"] == 1:
            root["a"] = root["x"] + 1
        else:
            root["b"] = root["x"] + 1

    root = {"x": torch.zeros(()), "a": None, "b": None}
    cap = EmulatedCapture(root)
    cap.capture(lambda _s: step(root))
    with pytest.raises(GraphMismatch, match=r"replaced \[\"env\['b'\]\"\] and not \[\"env\['a'\]\"\]"):
        cap.replay()


# ---------------------------------------------------------------------------------------------- the bookkeeping
class _Sim:
    def __init__(self):
        self.after = 0
        self.in_body = False
        self.graph_generation = 0

    @contextlib.contextmanager
    def graph_body(self, stream):
        self.in_body = True
        try:
            yield
        finally:
            self.in_body = False

    def count_step(self):
        self.after += 1


class _Env:
    """A stand-in: the state accumulates the actions; a step's outputs are new tensors, as the env's."""

    def __init__(self):
        self.device = torch.device("cpu")
        self.scene = SimpleNamespace(sim=_Sim())
        self.generation = 0
        self.state = torch.zeros(2, 3)
        self.bodies_in_graph = 0
        self.obs_buf = self.extras = None

    def graph_generation(self):
        return self.generation, self.scene.sim.graph_generation

    def step_body(self, actions):
        self.bodies_in_graph += self.scene.sim.in_body
        self.state += actions
        obs = TensorDict({"policy": self.state * 1.0}, batch_size=[2])
        return obs, self.state.sum(1), (self.state.sum(1) > 10).long(), {"time_outs": self.state[:, 0] > 5}


class _Replays:
    """A capture whose replay runs the body again and copies its outputs into the captured ones (as a graph
    writes them), or that fails when asked to."""

    def __init__(self, fail: bool = False):
        self.fail, self.body, self.outputs = fail, None, None

    def reset(self):
        self.body = None

    def capture(self, body):
        if self.fail:
            raise RuntimeError("operation not permitted when stream is capturing")
        self.body, self.outputs = body, body(None)
        return self.outputs

    def replay(self):
        out = self.body(None)
        for dst, src in zip(self.outputs, out):
            (dst.update_(src) if isinstance(dst, TensorDict) else dst.copy_(src))


def test_warm_up_capture_replay_and_copies_of_the_outputs():
    env = _Env()
    graph = EnvGraph(env, capture=_Replays(), warmup=2)
    outs = [graph.step(torch.ones(2, 3)) for _ in range(5)]
    assert (graph.eager_steps, graph.captures, graph.replays) == (2, 1, 2)
    assert env.scene.sim.after == 3  # the captured and replayed steps: the backend's count done around the graph
    assert env.bodies_in_graph == 3  # captured and replayed steps ran inside graph_body
    # every step's outputs kept their values (copies: the next replay overwrites the graph's own)
    assert [float(o[1][0]) for o in outs] == [3.0, 6.0, 9.0, 12.0, 15.0]
    assert [int(o[2][0]) for o in outs] == [0, 0, 0, 1, 1]
    assert env.obs_buf is outs[-1][0] and torch.equal(env.obs_buf["policy"], torch.full((2, 3), 5.0))


def test_captured_again_after_a_replaced_array_a_reset_or_a_mode_change():
    env = _Env()
    graph = EnvGraph(env, capture=_Replays(), warmup=1)
    act = torch.ones(2, 3)
    for _ in range(3):
        graph.step(act)
    assert graph.captures == 1
    env.scene.sim.graph_generation += 1  # a model array replaced: captured again at once, no new warm-up
    graph.step(act)
    env.generation += 1  # env.reset / load_state_dict
    graph.step(act)
    assert (graph.captures, graph.eager_steps) == (3, 1)
    with torch.inference_mode():  # another mode: compiled functions compile again, so warm up first
        graph.step(act)
        graph.step(act)
    assert (graph.captures, graph.eager_steps) == (4, 2)
    assert torch.equal(env.state, torch.full((2, 3), 7.0))  # every step ran once


def test_a_capture_that_fails_twice_warns_once_and_the_env_steps_eagerly():
    """The first failure warms up again and tries once more; the second warns once, naming both reasons."""
    env = _Env()
    graph = EnvGraph(env, capture=_Replays(fail=True), warmup=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(6):
            graph.step(torch.ones(2, 3))
    msgs = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(msgs) == 1 and "failed 2 times" in msgs[0]
    assert msgs[0].count("RuntimeError: operation not permitted when stream is capturing") == 2
    # steps 1 and 3 warmed up, 2 and 4 tried to capture (and ran eagerly), 5 and 6 eager
    assert graph.captures == 0 and graph.eager_steps == 6 and torch.equal(env.state, torch.full((2, 3), 6.0))


def test_a_capture_that_fails_once_is_tried_again_after_a_warm_up():
    env = _Env()
    replays = _Replays(fail=True)
    graph = EnvGraph(env, capture=replays, warmup=1)
    graph.step(torch.ones(2, 3))
    graph.step(torch.ones(2, 3))  # the capture fails: eager
    replays.fail = False
    for _ in range(4):
        graph.step(torch.ones(2, 3))  # a warm-up step, the capture, two replays
    assert (graph.eager_steps, graph.captures, graph.replays, graph.error) == (3, 1, 2, None)
    assert len(graph.failures) == 1 and torch.equal(env.state, torch.full((2, 3), 6.0))


def test_cuda_graph_needs_a_warp_backend():
    task = load_task("base", overrides={"scene": {"backend": "cpu", "num_workers": 0, "cuda_graph": True}})
    with pytest.raises(ConfigError, match=r"scene.cuda_graph.*needs a Warp backend.*not 'cpu'"):
        LocomotionEnv(task, num_envs=2, verbose=False)


# ---------------------------------------------------------------------------------------------- the managers
SMALL = {"terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}
EVENTFUL = {"env": {"episode_length_s": 0.2},
            "commands": {"base_velocity": {"resampling_time_s": [0.05, 0.1]}},
            "events": {"push": {"func": "push_robot", "mode": "interval", "interval_s": [0.04, 0.08],
                                "params": {"velocity_range": [-0.5, 0.5]}}}}
"""Episodes of 10 steps, commands resampled and robots pushed every few steps."""
SWITCHING = {"curriculum": {"penalties": {"params": {"threshold": 0.0}}}}
"""base's penalties switch on at the first reset with any tracking reward: a flag kept across steps."""


@pytest.mark.parametrize("task", ["base", "rough", "speed", "climb"])
def test_every_task_keeps_its_state_in_place_for_a_graph(task):
    """The managers, curricula and events of every task, replayed as a graph would replay them (the ``cpu``
    backend's host state left out of the walk: no graph holds it; needs no MuJoCo Warp, so CI runs it): the step
    replayed 20 times gives the eager env's outputs bit for bit, with resets, pushes and curricula that decide
    (thresholds lowered: the penalties and the speed range switch, terrain rows move)."""
    curriculum = {"penalties": {"params": {"threshold": 0.0}}}
    if task == "speed":
        curriculum["speed"] = {"params": {"threshold": -1.0}}
    overrides = {**SMALL, **EVENTFUL, "curriculum": curriculum, "scene": {"backend": "cpu", "num_workers": 0}}
    envs = [LocomotionEnv(load_task(task, overrides=overrides), num_envs=4, seed=0, verbose=False) for _ in "ab"]
    eager, graphed = envs
    g = torch.Generator().manual_seed(0)
    actions = torch.zeros(4, eager.num_actions)  # the graph's input
    cap = EmulatedCapture(graphed, skip=(graphed.scene.sim,))
    try:
        for i in range(24):
            act = torch.randn(4, eager.num_actions, generator=g) * 2
            a = eager.step(act)
            actions.copy_(act)
            if i < 3:
                b = graphed.step(act)
            elif i == 3:
                b = cap.capture(lambda _s: graphed.step_body(actions))
            else:
                cap.replay()
                b = cap.outputs
            for k in a[0].keys():  # noqa: SIM118 - a TensorDict iterates over its batch
                assert torch.equal(a[0][k], b[0][k]), (i, k)
            assert torch.equal(a[1], b[1]) and torch.equal(a[2], b[2]), i
        values = eager.curriculum_manager.values_as_floats()
        assert values == graphed.curriculum_manager.values_as_floats()
        assert values["penalties"] == 1.0 and values.get("speed", 1.1) > 1.0  # decided during the replays
    finally:
        for env in envs:
            env.close()


# ---------------------------------------------------------------------------------------------- the env
@pytest.fixture(scope="module")
def warp():
    return pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")


def _env(task: str, overrides: dict, graph: bool, compile: bool = False) -> LocomotionEnv:
    scene = {"backend": "warp-cpu", "num_workers": 0, "compile": compile, "cuda_graph": graph}
    return LocomotionEnv(load_task(task, overrides={**SMALL, **overrides, "scene": scene}), num_envs=4, seed=0,
                         verbose=False)


def _same_steps(task: str, overrides: dict, steps: int, compile: bool = False) -> tuple[LocomotionEnv, int]:
    """Step an eager and a graphed env alike; assert every output and the published state equal bit for bit;
    returns the graphed env (open) and the number of robot resets."""
    eager, graphed = _env(task, overrides, False, compile), _env(task, overrides, True, compile)
    g = torch.Generator().manual_seed(0)
    resets = 0
    try:
        for i in range(steps):
            act = torch.randn(4, eager.num_actions, generator=g) * 2
            if i == 6:
                act[1, 3] = float("nan")
            a, b = eager.step(act), graphed.step(act)
            for k in a[0].keys():  # noqa: SIM118 - a TensorDict iterates over its batch
                assert torch.equal(a[0][k], b[0][k]), (i, k)
            assert torch.equal(a[1], b[1]) and torch.equal(a[2], b[2]), i
            assert torch.equal(a[3]["time_outs"], b[3]["time_outs"]), i
            resets += int(a[2].sum())
        for f in dataclasses.fields(eager.state):
            assert torch.equal(getattr(eager.state, f.name), getattr(graphed.state, f.name)), f.name
        assert eager.episode_log.read() == graphed.episode_log.read()
        assert eager.curriculum_manager.values_as_floats() == graphed.curriculum_manager.values_as_floats()
    finally:
        eager.close()
    return graphed, resets


def test_a_graphed_env_steps_bit_for_bit_as_the_eager_one(warp):
    env, resets = _same_steps("base", {**EVENTFUL, **SWITCHING}, steps=30)
    try:
        assert resets > 6  # short episodes, random actions, a non-finite one
        assert env.curriculum_manager.values_as_floats()["penalties"] == 1.0  # the flag switched during replays
        assert (env.graph.captures, env.graph.replays, env.graph.error) == (1, 30 - 1 - env.graph.warmup, None)
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("task", ["base", "rough"])
def test_a_graphed_compiled_env_steps_bit_for_bit_as_the_eager_one(warp, task):
    """What runs on CUDA (scene.compile), on Warp's CPU device: rough's terrain curriculum moves rows too."""
    env, resets = _same_steps(task, EVENTFUL, steps=16, compile=True)
    try:
        assert resets > 2 and env.graph.captures == 1 and env.graph.error is None
    finally:
        env.close()


def test_reset_and_a_new_per_robot_field_capture_again(warp):
    env = _env("base", EVENTFUL, True)
    try:
        act = torch.zeros(4, env.num_actions)
        for _ in range(5):
            env.step(act)
        assert env.graph.captures == 1
        env.reset()
        env.step(act)
        assert env.graph.captures == 2
        env.scene.sim.set_model_field("body_mass", torch.ones(4, dtype=torch.bool),
                                      torch.as_tensor(env.scene.model.body_mass).repeat(4, 1) * 1.1)
        env.step(act)
        assert env.graph.captures == 3 and env.graph.error is None
    finally:
        env.close()


def test_a_replayed_step_reads_nothing_back(warp):
    """Around the graph only Python runs (counters, copies of the outputs): no host read or upload per replayed
    step, the backend's once-per-``check_every`` checks aside."""
    from dls_quadruped.core.sync_probe import sync_probe

    env = _env("base", EVENTFUL, True)
    try:
        g = torch.Generator().manual_seed(1)
        acts = [torch.randn(4, env.num_actions, generator=g) for _ in range(16)]
        for a in acts[:5]:  # warm-up and capture
            env.step(a)
        with sync_probe() as report:
            for a in acts[5:]:
                env.step(a)
        assert env.graph.replays == 16 - 3 - 1  # the eager warm-up, the capture
        backend = {"dls_quadruped/sim/warp_backend.py:_check_overflow",
                   "dls_quadruped/sim/warp_inputs.py:raise_flagged"}
        assert report.outside(backend) == {}, report.by_site()
    finally:
        env.close()


def test_training_through_the_graph_learns_the_same_weights(warp, tmp_path, monkeypatch):
    """rsl-rl's rollouts (inference mode; it keeps the observations it acted on until the step returns, hence the
    copies) and the PPO update, with the env step replayed: two iterations give the eager run's actor bit for bit."""
    from dls_quadruped.learning import train

    replays = []
    replay = EmulatedCapture.replay
    monkeypatch.setattr(EmulatedCapture, "replay", lambda self: replays.append(1) or replay(self))
    actors = []
    for graph in (False, True):
        run_dir = train.main(["--task", "base", "--num-envs", "4", "--iterations", "2", "--backend", "warp-cpu",
                              "--num-workers", "0", "--seed", "3", "--log-root", str(tmp_path / str(graph)),
                              "--set", f"scene.cuda_graph={str(graph).lower()}", "--set", "scene.compile=false"])
        actors.append(torch.load(next(run_dir.glob("model_*.pt")), weights_only=False)["actor_state_dict"])
    assert len(replays) == 2 * 24 - 3 - 1  # two iterations of 24 steps: all but the warm-up and the capture replayed
    assert actors[0].keys() == actors[1].keys()
    for k in actors[0]:
        assert torch.equal(actors[0][k], actors[1][k]), k


def test_the_cuda_capture_registers_warp_on_the_stream_it_hands_the_step(monkeypatch):
    """``CudaCapture`` without a GPU, its CUDA and Warp calls recorded by stand-ins: Warp's external capture begins
    on the very ``wp.Stream`` object the step gets (Warp finds a capture by that object: MuJoCo Warp's solver loop
    becomes a conditional node only then), inside torch's capture on the matching torch stream; it ends even when
    the step raises; the graph is replayed once after the capture (which ran nothing)."""
    import sys

    from dls_quadruped.envs.env_graph import CudaCapture

    calls = []

    class _Ctx:
        def __init__(self, name, *args, **kwargs):
            self.name, self.args, self.kwargs = name, args, kwargs

        def __enter__(self):
            calls.append(("enter", self.name, self.args, self.kwargs))

        def __exit__(self, *exc):
            calls.append(("exit", self.name))

    class _Graph:
        def replay(self):
            calls.append(("replay",))

    torch_stream = SimpleNamespace(wait_stream=lambda other: calls.append(("wait", other)))
    wstream = SimpleNamespace(name="warp view of the capture stream")
    fake_wp = SimpleNamespace(
        stream_from_torch=lambda s: wstream if s is torch_stream else None,
        device_from_torch=lambda d: f"wp:{d}",
        ScopedDevice=lambda d: _Ctx("wp.ScopedDevice", d),
        ScopedStream=lambda s: _Ctx("wp.ScopedStream", s),
        CaptureMode=SimpleNamespace(THREAD_LOCAL="thread-local mode"),
        capture_begin=lambda **k: calls.append(("capture_begin", k)),
        capture_end=lambda **k: calls.append(("capture_end", k)))
    monkeypatch.setitem(sys.modules, "warp", fake_wp)
    monkeypatch.setattr(torch.cuda, "CUDAGraph", _Graph)
    monkeypatch.setattr(torch.cuda, "Stream", lambda device: torch_stream)
    monkeypatch.setattr(torch.cuda, "current_stream", lambda device: "the current stream")
    monkeypatch.setattr(torch.cuda, "graph", lambda g, stream, capture_error_mode: _Ctx(
        "torch.cuda.graph", stream=stream, capture_error_mode=capture_error_mode))

    got = []
    cap = CudaCapture(torch.device("cuda:0"))
    out = cap.capture(lambda stream: got.append(stream) or "outputs")
    assert out == "outputs" and got == [wstream]
    assert calls[0] == ("wait", "the current stream")  # the capture stream starts after the queued work
    assert ("enter", "wp.ScopedStream", (wstream,), {}) in calls
    opened = ("enter", "torch.cuda.graph", (), {"stream": torch_stream, "capture_error_mode": "thread_local"})
    assert opened in calls
    # Warp is told the capture is external and opened thread-local, as torch opened it
    begin = calls.index(("capture_begin", {"stream": wstream, "force_module_load": False, "external": True,
                                           "capture_mode": "thread-local mode"}))
    end = calls.index(("capture_end", {"stream": wstream}))
    assert calls.index(opened) < begin < end
    assert end < calls.index(("exit", "torch.cuda.graph")) < calls.index(("replay",)) == len(calls) - 1

    calls.clear()
    with pytest.raises(RuntimeError, match="inside the step"):
        cap.capture(lambda stream: (_ for _ in ()).throw(RuntimeError("inside the step")))
    assert ("capture_end", {"stream": wstream}) in calls and ("replay",) not in calls


def test_the_gymnasium_view_of_a_graphed_env(warp):
    """Its final observations are taken inside the step by Python a graph does not replay: refused with
    ``final_obs`` on, naming the way out; with ``final_obs="none"`` the view steps as the eager one."""
    from dls_quadruped.envs.gym_env import LocomotionVectorEnv

    overrides = {**SMALL, **EVENTFUL}
    with pytest.raises(ValueError, match=r"final_obs='truncated'.*use final_obs='none' or scene.cuda_graph: false"):
        LocomotionVectorEnv(4, overrides={**overrides, "scene": {"backend": "warp-cpu", "cuda_graph": True}})
    views = [LocomotionVectorEnv(4, seed=0, final_obs="none", overrides={
        **overrides, "scene": {"backend": "warp-cpu", "num_workers": 0, "cuda_graph": graph}})
        for graph in (False, True)]
    try:
        g = torch.Generator().manual_seed(0)
        ended = 0
        for _ in range(12):
            act = torch.randn(4, 28, generator=g) * 2
            (oa, ra, ta, ua, _), (ob, rb, tb, ub, _) = (v.step(act) for v in views)
            assert all(torch.equal(oa[k], ob[k]) for k in oa) and torch.equal(ra, rb)
            assert torch.equal(ta, tb) and torch.equal(ua, ub)
            ended += int((ta | ua).sum())
        assert ended > 0 and views[1].env.graph.replays == 12 - 3 - 1
    finally:
        for v in views:
            v.close()
