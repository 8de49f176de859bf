"""Seeds in lockstep (learning/distill_batched.py) against single runs (DistillTrainer), and the
slot collection that feeds them."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.learning.collect import SlidingWindows, collect_slots
from dls_quadruped.learning.dataset import DiskDataset
from dls_quadruped.learning.distill_batched import (
    SeedGroupTrainer,
    StudentStack,
    gradient_steps,
    new_students,
)
from dls_quadruped.learning.distill_config import load_distill_config
from dls_quadruped.learning.distill_trainer import DistillTrainer
from dls_quadruped.mpc.encodings import encoded_dim

HIDDEN = [16, 16]


def _cfg(seed: int = 0, **train):
    return load_distill_config(overrides={
        "algorithm": "naive", "encoding": {"p": "first", "F": "spline", "horizon": 5, "dt": 0.02},
        "train": {"epochs": 3, "datapoints_per_epoch": 100, "dataset_cap": 1000, "batch_size": 32, "seed": seed,
                  **train}})


@pytest.fixture
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.mark.parametrize("schedule", ["full", "dagger_steps"])
def test_lockstep_seeds_train_like_single_runs(tmp_path, one_thread, schedule, linear_env):
    """Same datasets, seeds 0 and 1: the stacked trainer's students equal two DistillTrainer runs
    (initialisation, mini-batch order, Adadelta, step decay, DAgger-step subsets) to float rounding."""
    env = linear_env(4, torch.eye(4), torch.zeros(4, 28))
    dim = encoded_dim(_cfg().encoding.to_encoding())
    gen = torch.Generator().manual_seed(7)
    datasets = []
    for k in range(2):
        ds = DiskDataset.create(tmp_path / f"d{k}", 4, dim, 1000)
        ds.append(torch.randn(300, 4, generator=gen) * 3 + 1, torch.randn(300, dim, generator=gen))
        datasets.append(ds)
    batched = SeedGroupTrainer(_cfg(naive_schedule=schedule), [0, 1], env, None, tmp_path / "b", HIDDEN, "elu",
                               datasets=datasets)
    steps = []
    for _ in range(3):
        steps.append(batched.train_pass()["steps"])
        batched.epoch += 1
    assert sum(steps) == gradient_steps(_cfg(naive_schedule=schedule))
    assert steps == ([10, 10, 10] if schedule == "full" else [4, 7, 10])  # ceil(100 (i + 1) / 32) rows of 300
    for k in range(2):
        single = DistillTrainer(_cfg(seed=k, naive_schedule=schedule), env, None, tmp_path / f"s{k}", HIDDEN, "elu",
                                printer=lambda *a, **kw: None)
        single.dataset = datasets[k]
        single.student.obs_normalizer.train()
        single.student.obs_normalizer.update(datasets[k].ordered()[0])
        for _ in range(3):
            single.train_pass()
            single.epoch += 1
        want, got = single.student.state_dict(), batched.students[k].state_dict()
        assert want.keys() == got.keys()
        for name in want:
            torch.testing.assert_close(got[name], want[name], rtol=1e-4, atol=1e-5, msg=name)
    moved = batched.students[0].mlp[0].weight - new_students([0], 4, _cfg(), HIDDEN, "elu")[0].mlp[0].weight
    assert moved.abs().max() > 1e-3  # they trained (the test would pass on two untouched copies otherwise)


def test_stack_forward_is_each_students_own():
    students = new_students([3, 4, 5], 4, _cfg(), HIDDEN, "elu")
    stack = StudentStack(students)
    obs = torch.randn(3, 6, 4)
    want = torch.stack([s.net(obs[k]) for k, s in enumerate(students)])
    torch.testing.assert_close(stack.net(obs), want, rtol=1e-5, atol=1e-6)
    assert len(list(stack.parameters())) == 2 * 3  # weights and biases of 3 layers, students not registered


def test_slots_get_their_own_robots_windows(scripted_env, tag_expert):
    """4 robots in 2 slots: slot 0's windows come from robots 0-1, slot 1's from 2-3, each slot gets
    exactly ``count``; the student acts on every robot (beta 0.5 mixes it in)."""
    env = scripted_env([20, 20, 20, 20])
    got: dict[int, list[torch.Tensor]] = {0: [], 1: []}
    seen = []

    def student(obs):
        seen.append(len(obs))
        return torch.zeros(len(obs), 28)

    info = collect_slots(env, tag_expert, [lambda a: a[..., 0], lambda a: a[..., 0] + 0.5], 7, horizon=2, stride=1,
                         sink=lambda s, o, lab: got[s].append((o, lab)), beta_value=0.5, student=student)
    assert info["datapoints"] == [7, 7] and set(seen) == {4}
    for s in (0, 1):
        obs = torch.cat([o for o, _ in got[s]])
        labels = torch.cat([lab for _, lab in got[s]])
        assert len(obs) == 7 and set(obs[:, 0].tolist()) <= {2.0 * s, 2.0 * s + 1}
        first = 100 * obs[:, 0] + obs[:, 1] + 0.5 * s  # the tag of the window's first step, then the encoder's mark
        torch.testing.assert_close(labels[:, 0], first)
    torch.testing.assert_close(env.applied[0], 0.5 * tag_expert(torch.stack(
        [torch.arange(4.0), torch.zeros(4), torch.zeros(4)], 1)))


def test_a_continued_collection_is_one_long_one(scripted_env, tag_expert):
    """Two calls of 8 datapoints on one ring (4 robots: two steps of windows each) give the windows of
    one call of 16: the second call does not push the step the first one ended on again."""
    def run(counts):
        env = scripted_env([9, 9, 30, 30])
        ring = SlidingWindows(4, 3, 28, horizon=3, stride=2)
        got = []
        for c in counts:
            collect_slots(env, tag_expert, [lambda a: a[..., 0]], c, horizon=3, stride=2,
                          sink=lambda s, o, lab: got.append(lab), windows=ring)
        return torch.cat(got)

    torch.testing.assert_close(run([8, 8]), run([16]))
    assert len(run([8, 8])) == 16


def test_settings_of_different_output_sizes_train_together_as_alone(tmp_path, one_thread, linear_env):
    """first-spline (D = 64) and discrete-discrete (D = 108) in one stack (the smaller padded): each
    student equals the one trained alone; the padding columns stay zero."""
    env = linear_env(4, torch.eye(4), torch.zeros(4, 28))
    cfgs = [_cfg(), load_distill_config(overrides={**_cfg().to_dict(), "encoding": {
        "p": "discrete", "F": "discrete", "horizon": 5, "dt": 0.02}})]
    gen = torch.Generator().manual_seed(3)
    data = []
    for i, c in enumerate(cfgs):
        ds = DiskDataset.create(tmp_path / f"d{i}", 4, encoded_dim(c.encoding.to_encoding()), 1000)
        ds.append(torch.randn(200, 4, generator=gen), torch.randn(200, encoded_dim(c.encoding.to_encoding()),
                                                                  generator=gen))
        data.append(ds)
    both = SeedGroupTrainer(cfgs, [1], env, None, [tmp_path / "a", tmp_path / "b"], HIDDEN, "elu", datasets=data)
    alone = [SeedGroupTrainer(c, [1], linear_env(2, torch.eye(4), torch.zeros(4, 28)), None, tmp_path / f"s{i}",
                              HIDDEN, "elu", datasets=[data[i]]) for i, c in enumerate(cfgs)]
    for t in (both, *alone):
        for _ in range(2):
            t.train_pass()
            t.epoch += 1
    assert both.stack.dims == [64, 108] and both.stack.weight[-1][0, :, 64:].abs().max() == 0
    for i in range(2):
        want, got = alone[i].state_dicts()[0], both.state_dicts(i)[0]
        for name in want:
            torch.testing.assert_close(got[name], want[name], rtol=1e-4, atol=1e-5, msg=name)
