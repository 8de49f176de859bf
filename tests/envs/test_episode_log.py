"""``envs/episode_log.py``: per-step episode values summed on the device, read once as rsl-rl's logger would
average them (the mean over the steps that had resets)."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.envs.episode_log import EpisodeLog


def _t(x: float) -> torch.Tensor:
    return torch.tensor(x)


def test_the_read_is_the_mean_over_steps_with_resets_and_restarts_the_sums():
    log = EpisodeLog("cpu")
    assert log.read() == {}
    log.add({"a": _t(1.0), "b": _t(4.0)}, torch.tensor(True))
    log.add({"a": _t(0.0), "b": _t(0.0)}, torch.tensor(False))  # no reset: a step rsl-rl's logger never sees
    log.add({"a": _t(2.0), "b": _t(-1.0)}, torch.tensor(True))
    assert log.read() == {"a": pytest.approx(1.5), "b": pytest.approx(1.5)}  # (1 + 2) / 2, (4 - 1) / 2
    assert log.read() == {}  # restarted; no step with resets since
    log.add({"a": _t(5.0), "b": _t(7.0)}, torch.tensor(False))
    assert log.read() == {}


def test_a_key_that_appears_later_averages_over_its_own_steps_and_nan_of_a_quiet_step_is_dropped():
    log = EpisodeLog("cpu")
    log.add({"a": _t(3.0)}, torch.tensor(True))
    log.add({"a": _t(1.0), "c": _t(10.0)}, torch.tensor(True))
    log.add({"a": _t(float("nan")), "c": _t(float("nan"))}, torch.tensor(False))  # where, not a product: no NaN
    log.add({"a": _t(2.0), "c": _t(20.0)}, torch.tensor(True))
    assert log.keys == ("a", "c")
    assert log.read() == {"a": pytest.approx(2.0), "c": pytest.approx(15.0)}


def test_sums_begun_under_inference_mode_are_read_and_added_to_outside_it():
    """rsl-rl collects rollouts under ``torch.inference_mode``; the log is read by the runner and stepped by other
    callers outside it."""
    log = EpisodeLog("cpu")
    with torch.inference_mode():
        log.add({"a": _t(1.0)}, torch.tensor(True))
    assert log.read() == {"a": pytest.approx(1.0)}
    log.add({"a": _t(3.0)}, torch.tensor(True))
    with torch.inference_mode():
        log.add({"a": _t(5.0)}, torch.tensor(True))
    assert log.read() == {"a": pytest.approx(4.0)}


def test_adding_reads_nothing_back():
    from dls_quadruped.core.sync_probe import sync_probe

    log = EpisodeLog("cpu")
    log.add({"a": _t(1.0)}, torch.tensor(True))  # the first add lays out the keys
    values, flag = {"a": _t(2.0)}, torch.tensor(True)
    with sync_probe() as report:
        for _ in range(5):
            log.add(values, flag)
    assert report.total == 0, report.by_site()
    assert log.read() == {"a": pytest.approx(11.0 / 6.0)}
