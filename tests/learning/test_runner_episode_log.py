"""The runner hands rsl-rl's logger the env's episode values once per iteration (``LocomotionEnv.episode_log``),
as one entry of its ``ep_extras``: the logger then reports the mean over the iteration's steps with resets."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from dls_quadruped.envs.episode_log import EpisodeLog
from dls_quadruped.learning.runner import AtomicOnPolicyRunner


def _runner(writer: object | None) -> SimpleNamespace:
    log = EpisodeLog("cpu")
    return SimpleNamespace(env=SimpleNamespace(episode_log=log), logger=SimpleNamespace(writer=writer, ep_extras=[]))


def test_the_iterations_episode_values_reach_the_logger_once():
    runner = _runner(writer=object())
    log = runner.env.episode_log
    log.add({"Episode_Termination/time_out": torch.tensor(2.0)}, torch.tensor(True))
    log.add({"Episode_Termination/time_out": torch.tensor(0.0)}, torch.tensor(False))
    log.add({"Episode_Termination/time_out": torch.tensor(1.0)}, torch.tensor(True))
    AtomicOnPolicyRunner._collect_episode_log(runner)
    assert runner.logger.ep_extras == [{"Episode_Termination/time_out": pytest.approx(1.5)}]
    AtomicOnPolicyRunner._collect_episode_log(runner)  # nothing new: no empty entry
    assert len(runner.logger.ep_extras) == 1


def test_a_rank_without_a_writer_reads_and_restarts_its_sums_but_logs_nothing():
    runner = _runner(writer=None)
    runner.env.episode_log.add({"a": torch.tensor(3.0)}, torch.tensor(True))
    AtomicOnPolicyRunner._collect_episode_log(runner)
    assert runner.logger.ep_extras == [] and runner.env.episode_log.read() == {}
