"""What an evaluation scenario is (``Scenario``), its options, and the evaluation reward.

The table of scenarios by name is ``scenarios.SCENARIOS``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from dls_quadruped.envs.config import TASKS_DIR, load_task
from dls_quadruped.envs.sections import replace_sections  # noqa: F401 - the scenarios build their tasks with it

EVAL_REWARDS_FILE = TASKS_DIR / "_base_rewards.yaml"
"""Table 4, base column: the evaluation reward of every scenario and policy."""

SPLITS = ("test", "validation")
"""Episode sets: checkpoints and experts are chosen on ``validation`` and reported on ``test``."""

VALIDATION_SEED_OFFSET = 1_000_003
"""``validation`` episodes of seed s are the ``test`` episodes of seed s + this: every command, push and noise
draw comes from (seed, episode key) (``envs/schedule.py``, the scenarios' command generators), so the two
sets share no episode for any seed below the offset, and repeated seeds 0, 1, 2, ... of a report stay test."""


def split_seed(seed: int, split: str) -> int:
    """The seed whose episodes are ``split``'s episodes of ``seed`` (``SPLITS``).

    Raises:
        ValueError: an unknown split, or a seed outside [0, VALIDATION_SEED_OFFSET) (its sets would overlap).
    """
    if split not in SPLITS:
        raise ValueError(f"unknown episode split {split!r}; allowed: {list(SPLITS)}")
    if not 0 <= seed < VALIDATION_SEED_OFFSET:
        raise ValueError(f"seed must be in [0, {VALIDATION_SEED_OFFSET}) so test and validation episodes stay "
                         f"disjoint, got {seed}")
    return seed + VALIDATION_SEED_OFFSET if split == "validation" else seed


@dataclass(frozen=True)
class EvalOptions:
    """Size and placement of an evaluation.

    Attributes:
        episodes: episodes per condition of the scenario (the whole set for ``simple``, ``forward``
            and ``survival``; per speed, step height or grid cell for the sweeps), all run in
            parallel (one env each).
        seed: seed of the commands and of the env.
        num_workers: simulator worker processes (-1 one per core, 0 in-process).
        episode_length_s: [s] episode length; None keeps the task's (15 s).
        device: torch device of the env and the policy.
    """

    episodes: int = 256
    seed: int = 0
    num_workers: int = -1
    episode_length_s: float | None = None
    device: str = "cpu"


@dataclass(frozen=True)
class Scenario:
    """One evaluation scenario.

    Attributes:
        name: command-line name.
        description: one line for ``--help`` and the results.
        evaluate: (policy path, options) -> JSON-able results.
        plot: (results, png path) -> None.
        default_episodes: ``EvalOptions.episodes`` when the command line does not say (the small
            size: one policy in about two minutes on two cores).
        summary: results -> a few lines for the terminal; None: the tracking headline.
        episodes_multiple: ``EvalOptions.episodes`` must be a multiple of this (2 where every
            command has a mirrored twin).
    """

    name: str
    description: str
    evaluate: Callable[[Path, EvalOptions], dict]
    plot: Callable[[dict, Path], None]
    default_episodes: int = 256
    summary: Callable[[dict], str] | None = None
    episodes_multiple: int = 1


def eval_rewards() -> dict:
    """The evaluation reward terms (Table 4, base column), as a task ``rewards`` section."""
    return copy.deepcopy(load_task(EVAL_REWARDS_FILE).data["rewards"])
